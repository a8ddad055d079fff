"""Model files that cannot run code (tendon2r_gym.artifacts.files): a pickle dropped into a bundle,
passed as --model or --init-from, or left in a run folder by an earlier version is refused
without the trust option, naming the file and the option, and never unpickled; a model zip's
pickled entries are never unpickled; the shipped models load without pickle and act as they
did with their pickled statistics, bit for bit."""

import base64
import contextlib
import hashlib
import json
import pickle
import shutil
import zipfile
from collections import OrderedDict
from pathlib import Path

import cloudpickle
import numpy as np
import pytest
import torch
import yaml
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

import tendon2r_gym  # noqa: F401  (registers Tendon2R-v0)
from tendon2r_gym.app import cli, tools
from tendon2r_gym.artifacts.bundle import bundle_meta, bundle_names, bundled_model
from tendon2r_gym.artifacts.files import (
    TRUST_HELP,
    PickleRefused,
    convert_stats,
    load_policy,
    read_stats,
    trusting_pickle,
)
from tendon2r_gym.artifacts.runs import RunFolder, training_record
from tendon2r_gym.envs.registration import make as make_env
from tendon2r_gym.policies import inference
from tendon2r_gym.policies.learned import PPOPolicy
from tendon2r_gym.presets import MODELS_DIR
from tendon2r_gym.training import Hyperparams
from tendon2r_gym.training.init_from import initial_model, load_initial
from tendon2r_gym.training.manager import _load_newest, make_vec_env

BUNDLE = "default"
STATS, LEGACY = "best_model_vecnormalize.npz", "best_model_vecnormalize.pkl"

#: Per shipped model, the digest of :func:`fingerprint` (its normalized observations and its
#: actions on them) computed with SB3's PPO.load and the pickled statistics it shipped with
#: before they were converted to npz.
DIGESTS = {
    "default/seed_0": "511d70091a8b1b44",
    "default/seed_1": "19b432a3d3e1feb7",
    "default/seed_2": "30fe89fa563f7df5",
    "default_scratch/seed_0": "b3c7b99efe70ec1f",
    "default_scratch/seed_1": "1e16270a7e554eb4",
    "default_scratch/seed_2": "6ce22363794bf8a2",
    "generalist/seed_0": "29f3cb715e1355de",
    "generalist_pull_only/seed_0": "ddc9fbbb6288f57e",
    "generalist_real/seed_0": "cf2ec48fda935ecb",
    "generalist_scratch/seed_0": "253b99a84b6b215c",
    "pull_only/seed_0": "0e357579d89a70dd",
    "pull_only/seed_1": "811920a26f97eacf",
    "pull_only/seed_2": "f70475f6e02956b0",
    "pull_only_scratch/seed_0": "4f737970d545f572",
    "pull_only_scratch/seed_1": "84d9d32683eb3c3c",
    "pull_only_scratch/seed_2": "f293e6620c9bc187",
    "random_reference/seed_0": "c1cb147b1bf10e69",
    "real_arm/seed_0": "d92a1b6469c18545",
    "report_002/seed_0": "654534c1e2225ef4",
    "report_002/seed_1": "2affc01c7cf639d6",
    "report_002/seed_2": "cb43617d5df0ed38",
    "report_002_scratch/seed_0": "e90f5f5bafd5c731",
    "report_002_scratch/seed_1": "61151ef4ecac1dc4",
    "report_002_scratch/seed_2": "c494d5042b9ec383",
}


class Payload:
    """Unpickling it creates the file ``marker`` (where a hostile file could run anything)."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def hostile(marker: Path) -> bytes:
    return pickle.dumps(Payload(marker))


def fingerprint(model, vecnorm) -> str:
    """The digest of a model's normalized observations and actions (the exact actor: the same
    bits on every machine) for fixed observations at scales up to the clipping."""
    seen = vecnorm.obs_rms.mean.size
    size = model.policy.observation_space.shape[0]
    n, stack = 16, size // seen  # a model of stacked frames sees several normalized ones
    rng = np.random.default_rng(0)
    raw = rng.normal(size=(n * stack, seen)) * rng.choice([0.01, 1.0, 10.0, 1000.0], (n * stack, 1))
    norm = vecnorm.normalize_obs(raw)
    actions, _ = inference.predict(model, norm.reshape(n, size))
    return hashlib.sha256(norm.tobytes() + actions.tobytes()).hexdigest()[:16]


@contextlib.contextmanager
def no_pickle(monkeypatch):
    """Every way into pickle (the stdlib's and cloudpickle's, which SB3's load uses) raises."""

    def refused(*args, **kwargs):
        raise AssertionError("pickle was called")

    class Refused(pickle.Unpickler):
        def __init__(self, *args, **kwargs):
            refused()

    with monkeypatch.context() as m:
        for module in (pickle, cloudpickle):
            m.setattr(module, "load", refused)
            m.setattr(module, "loads", refused)
        m.setattr(pickle, "Unpickler", Refused)
        yield


@pytest.fixture
def root(tmp_path) -> Path:
    """A copy of a shipped bundle (never the package's own)."""
    out = tmp_path / "models"
    shutil.copytree(MODELS_DIR / BUNDLE, out / BUNDLE)
    return out


def rewrite_zip(path: Path, **entries: bytes) -> None:
    """Rewrites the zip at ``path`` with ``entries`` replaced."""
    with zipfile.ZipFile(path) as z:
        kept = {name: z.read(name) for name in z.namelist()}
    with zipfile.ZipFile(path, "w") as z:
        for name, data in {**kept, **entries}.items():
            z.writestr(name, data)


def legacy(folder: Path) -> Path:
    """Turns a seed folder into one of an earlier version: its statistics as SB3's pickle."""
    stats = read_stats(folder / STATS)
    venv = DummyVecEnv(
        [lambda: make_env(**training_record(folder / "best_model.zip")["env_kwargs"])]
    )
    stats.vecnormalize(venv).save(str(folder / LEGACY))
    (folder / STATS).unlink()
    return folder / LEGACY


def test_a_pickle_in_a_bundle_or_a_model_path_is_refused_and_never_runs(root, tmp_path):
    folder, marker = root / BUNDLE / "seed_0", tmp_path / "marker"
    (folder / STATS).unlink()
    (folder / LEGACY).write_bytes(hostile(marker))
    model = bundled_model(BUNDLE, root=root)
    env = make_env(**training_record(model)["env_kwargs"])
    out, tuned = tmp_path / "out", tmp_path / "tuned"
    loads = {
        "PPOPolicy.load": lambda: PPOPolicy.load(model, env),
        "--model": lambda: cli.evaluate_main(
            ["--policy", "ppo", "--model", str(model), "--episodes", "1"]
        ),
        "--init-from": lambda: cli.train_main(
            ["--hyperparams", "default", "--run-dir", str(tuned), "--init-from", str(model)]
        ),
        "tendon2r-bundle": lambda: tools.bundle_main(
            ["--name", "copy", "--root", str(out), "--runs", str(folder)]
        ),
    }
    for name, load in loads.items():
        with pytest.raises(PickleRefused) as err:
            load()
        assert str(folder / LEGACY) in str(err.value), name
        assert "--trust-pickle" in str(err.value) and TRUST_HELP in str(err.value), name
        assert not marker.exists(), name
    assert not out.exists() and not tuned.exists(), "a refused command writes nothing"
    # What the option is for: with it, the pickle runs (here, it creates the marker).
    with pytest.raises(ValueError, match="is not a VecNormalize pickle"):
        PPOPolicy.load(model, env, trust_pickle=True)
    assert marker.exists()


def test_a_model_zips_pickled_entries_are_never_unpickled(root, tmp_path, monkeypatch):
    path, marker = root / BUNDLE / "seed_0" / "best_model.zip", tmp_path / "marker"
    env = make_env(**training_record(path)["env_kwargs"])
    before = PPOPolicy.load(path, env)
    with zipfile.ZipFile(path) as z:
        data = json.loads(z.read("data"))
    payload = {":serialized:": base64.b64encode(hostile(marker)).decode()}
    pickled = [k for k, v in data.items() if isinstance(v, dict) and ":serialized:" in v]
    assert {"policy_class", "observation_space", "action_space", "lr_schedule"} <= set(pickled)
    # Every pickled entry but the policy class (read by name from its opcodes) made hostile:
    # the model loads without pickle, and acts as before.
    others = {k: {**data[k], **payload} for k in pickled if k != "policy_class"}
    rewrite_zip(path, data=json.dumps({**data, **others}).encode())
    with no_pickle(monkeypatch):
        after = PPOPolicy.load(path, env)
    assert fingerprint(after.model, after.vecnormalize) == fingerprint(
        before.model, before.vecnormalize
    )
    assert not marker.exists()
    # A hostile policy class, a class not allowed, hostile weights: refused, naming the file.
    other_class = {":serialized:": base64.b64encode(pickle.dumps(OrderedDict)).decode()}
    cases = {
        "records the policy class a class that is not named by reference; allowed: ": {
            "data": json.dumps({**data, "policy_class": payload}).encode()
        },
        "records the policy class collections.OrderedDict; allowed: ": {
            "data": json.dumps({**data, "policy_class": other_class}).encode()
        },
        r"is not an SB3 model zip of plain weights \(policy.pth: UnpicklingError": {
            "policy.pth": hostile(marker)
        },
    }
    model = ["--policy", "ppo", "--model", str(path), "--episodes", "1"]
    for what, entries in cases.items():
        rewrite_zip(path, **{"data": json.dumps(data).encode(), **entries})
        for load in (lambda: PPOPolicy.load(path, env), lambda: cli.evaluate_main(model)):
            with pytest.raises(ValueError, match=what) as err:
                load()
            assert str(err.value).startswith(str(path)), what
            assert not marker.exists(), what
        if "policy class" in what:
            assert "stable_baselines3.common.policies.ActorCriticPolicy" in str(err.value)
        rewrite_zip(path, **{"policy.pth": _weights(MODELS_DIR / BUNDLE)})


def _weights(bundle: Path) -> bytes:
    with zipfile.ZipFile(bundle / "seed_0" / "best_model.zip") as z:
        return z.read("policy.pth")


def test_an_earlier_versions_statistics_load_only_with_the_trust_option(root, tmp_path):
    folder = root / BUNDLE / "seed_0"
    model = folder / "best_model.zip"
    env = make_env(**training_record(model)["env_kwargs"])
    plain = PPOPolicy.load(model, env)
    original = read_stats(folder / STATS)
    pkl = legacy(folder)
    with pytest.raises(PickleRefused, match=r"best_model_vecnormalize.pkl is a pickle .*--trust"):
        PPOPolicy.load(model, env)
    for load in (
        lambda: PPOPolicy.load(model, env, trust_pickle=True),
        lambda: _in_trust(lambda: PPOPolicy.load(model, env)),
    ):
        trusted = load()
        assert fingerprint(trusted.model, trusted.vecnormalize) == fingerprint(
            plain.model, plain.vecnormalize
        )
    short = ["--policy", "ppo", "--model", str(model), "--episodes", "1", "--episode-duration",
             "0.2"]  # fmt: skip
    with pytest.raises(PickleRefused):
        cli.evaluate_main(short)
    assert cli.evaluate_main([*short, "--trust-pickle"])["rms_deg"] == _with_npz(
        folder, original, short
    )
    # Bundling it (trusted) writes the npz, no pickle; so does the converter.
    out = tmp_path / "out"
    tools.bundle_main(["--name", "conv", "--root", str(out), "--runs", str(folder),
                       "--trust-pickle"])  # fmt: skip
    assert sorted(p.name for p in (out / "conv" / "seed_0").glob("*_vecnormalize*")) == [STATS]
    for converted in (read_stats(out / "conv" / "seed_0" / STATS),
                      convert_stats(pkl, tmp_path / "c.npz", trust_pickle=True)):  # fmt: skip
        assert _same_stats(converted, original)


def _in_trust(load):
    with trusting_pickle():
        return load()


def _with_npz(folder: Path, stats, argv: list[str]) -> list[float]:
    """The evaluation's RMS with the statistics back as the npz (and no pkl)."""
    stats.save(folder / STATS)
    (folder / LEGACY).rename(folder / "kept.pkl")
    try:
        return cli.evaluate_main(argv)["rms_deg"]
    finally:
        (folder / STATS).unlink()
        (folder / "kept.pkl").rename(folder / LEGACY)


def _same_stats(a, b) -> bool:
    arrays = a.arrays(), b.arrays()
    return arrays[0].keys() == arrays[1].keys() and all(
        arrays[0][k].dtype == arrays[1][k].dtype and np.array_equal(arrays[0][k], arrays[1][k])
        for k in arrays[0]
    )


def test_the_shipped_models_load_without_pickle_and_act_as_before(monkeypatch):
    assert not list(MODELS_DIR.rglob("*.pkl")), "the package ships no pickle"
    seen = {}
    with no_pickle(monkeypatch):
        for name in bundle_names():
            for seed in bundle_meta(name)["seeds"]:
                model = bundled_model(name, seed)
                env = make_env(**training_record(model)["env_kwargs"])
                policy = PPOPolicy.load(model, env)
                seen[f"{name}/seed_{seed}"] = fingerprint(policy.model, policy.vecnormalize)
                obs, info = env.reset(seed=0)
                policy.reset(info)
                assert np.all(np.isfinite(policy.predict(obs)[0]))
    assert seen == DIGESTS


def test_the_policy_built_without_pickle_is_sb3s():
    """load_policy's policy is SB3's PPO.load's: the same weights and spaces, and the same
    actions through the exact actor and through SB3's float32 predict."""
    for name in bundle_names():
        for seed in bundle_meta(name)["seeds"]:
            path = bundled_model(name, seed)
            ours, theirs = load_policy(path), PPO.load(path, device="cpu")
            assert type(ours.policy) is type(theirs.policy)
            a, b = ours.policy.state_dict(), theirs.policy.state_dict()
            assert list(a) == list(b) and all(torch.equal(a[k], b[k]) for k in a)
            for space in ("observation_space", "action_space"):
                x, y = getattr(ours, space), getattr(theirs, space)
                assert (x.shape, x.dtype) == (y.shape, y.dtype)
                assert np.array_equal(x.low, y.low) and np.array_equal(x.high, y.high)
            obs = np.random.default_rng(seed).normal(size=(8, *ours.observation_space.shape))
            for predict in (inference.predict, lambda m, o: m.policy.predict(o, None, None, True)):
                assert np.array_equal(predict(ours, obs)[0], predict(theirs, obs)[0]), name


def _tiny(tmp_path: Path) -> tuple[Path, Hyperparams]:
    base = Hyperparams.from_entry("default")
    hp = base.replace(
        env_kwargs={"preset": "default", "episode_duration": 0.1},
        ppo={**base.ppo, "n_steps": 64, "batch_size": 64, "n_epochs": 1},
        total_timesteps=256, n_envs=2, eval_freq=128, checkpoint_freq=128, eval_seeds=[0],
    )  # fmt: skip
    path = tmp_path / "ppo.yaml"
    path.write_text(yaml.safe_dump({"tiny": hp.to_dict()}))
    return path, hp


def test_training_saves_plain_statistics_and_resumes_and_fine_tunes_without_pickle(
    tmp_path, monkeypatch
):
    config, hp = _tiny(tmp_path)
    base = tmp_path / "run"
    argv = ["--config", str(config), "--hyperparams", "tiny", "--run-dir", str(base)]
    cli.train_main(argv)
    run = RunFolder(base / "seed_0")
    for stem in ("best_model", "last_model", "checkpoints/rl_model_vecnormalize_128_steps"):
        name = stem if stem.startswith("checkpoints") else f"{stem}_vecnormalize"
        assert run.file(f"{name}.npz").is_file(), stem
    assert [s.suffix for _, s in run.checkpoint_candidates()] == [".npz"] * 3
    # The newest state, as --resume reads it: no pickle, SB3's weights, optimizer and stats.
    with no_pickle(monkeypatch):
        model, vecnorm = _load_newest(run, make_vec_env(hp, 0), hp)
    saved = PPO.load(run.file("last_model.zip"), device="cpu")
    assert model.num_timesteps == saved.num_timesteps == 256
    _assert_same_state(model, saved)
    sb3 = VecNormalize.load(str(run.file("last_model_vecnormalize.pkl")), make_vec_env(hp, 0))
    assert np.array_equal(vecnorm.obs_rms.mean, sb3.obs_rms.mean)
    assert np.array_equal(vecnorm.obs_rms.var, sb3.obs_rms.var)
    assert (
        cli.train_main([*argv, "--resume", "--total-timesteps", "384"])["runs"][0]["timesteps"]
        >= 384
    )
    # A run of an earlier version (its statistics pickles alone) resumes only when trusted.
    for npz in run.path.rglob("*_vecnormalize*.npz"):
        npz.unlink()
    last, marker = run.file("last_model_vecnormalize.pkl"), tmp_path / "marker"
    kept = last.read_bytes()
    last.write_bytes(hostile(marker))
    with pytest.raises(PickleRefused, match=r"last_model_vecnormalize.pkl .*--trust-pickle"):
        cli.train_main([*argv, "--resume", "--total-timesteps", "512"])
    assert not marker.exists()
    last.write_bytes(kept)
    resumed = cli.train_main([*argv, "--resume", "--total-timesteps", "512", "--trust-pickle"])
    assert resumed["runs"][0]["timesteps"] >= 512
    # --init-from a bundle: its weights and statistics, read without pickle.
    tuned = hp.replace(init_from=BUNDLE)
    with no_pickle(monkeypatch):
        source = initial_model(tuned)
        model, vecnorm = load_initial(tuned, source, make_vec_env(hp, 0), 0, RunFolder(tmp_path))
    bundled = PPO.load(bundled_model(BUNDLE), device="cpu")
    _assert_same_state(model, bundled)
    assert model.num_timesteps == 0
    shipped = read_stats(bundled_model(BUNDLE).with_name(STATS))
    assert np.array_equal(vecnorm.obs_rms.mean, shipped.obs_mean)
    assert np.array_equal(vecnorm.obs_rms.var, shipped.obs_var)


def _assert_same_state(model, saved) -> None:
    a, b = model.policy.state_dict(), saved.policy.state_dict()
    assert list(a) == list(b) and all(torch.equal(a[k], b[k]) for k in a)
    x, y = model.policy.optimizer.state_dict(), saved.policy.optimizer.state_dict()
    assert x["param_groups"] == y["param_groups"]
    assert all(
        torch.equal(x["state"][i][k], y["state"][i][k]) for i in x["state"] for k in x["state"][i]
    )
