"""Nothing lost, nothing crashes: bundling never deletes or writes outside its bundle, replaces
one only when asked and only once the new one is complete; every corrupt model-side file (model
zip, VecNormalize statistics, bundle.json) is one ValueError that names it."""

import json
import os
import pathlib
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import gymnasium as gym
import pytest

import tendon2r_gym  # noqa: F401  (registers Tendon2R-v0)
from tendon2r_gym.app import cli, tools
from tendon2r_gym.artifacts import bundle
from tendon2r_gym.artifacts.bundle import bundle_meta, bundle_names, bundle_runs, bundled_model
from tendon2r_gym.artifacts.files import (
    PickleRefused,
    load_model,
    load_policy,
    load_ppo,
    load_vecnormalize,
)
from tendon2r_gym.policies.learned import PPOPolicy
from tendon2r_gym.presets import MODELS_DIR

REPO = Path(__file__).resolve().parents[1]
#: Two bundles of the default arm whose models observe different sizes (24 and 26 entries).
SMALL, OTHER = "default", "default_scratch"


def files_under(root: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


@pytest.fixture(scope="module")
def models(tmp_path_factory) -> Path:
    """A copy of the bundled models (never the package's own)."""
    root = tmp_path_factory.mktemp("copy") / "models"
    shutil.copytree(MODELS_DIR, root)
    return root


@pytest.fixture
def runs(tmp_path) -> list[Path]:
    """Two finished run folders (seeds 0 and 1): copies of a bundle's seed folders."""
    out = []
    for seed in (0, 1):
        out.append(tmp_path / "runs" / f"seed_{seed}")
        shutil.copytree(MODELS_DIR / SMALL / f"seed_{seed}", out[-1])
    return out


# -- A: bundling ------------------------------------------------------------------------------
BAD_NAMES = [
    [],  # no --name
    ["--name", "../escape"],
    ["--name", "{tmp}/abs"],
    ["--name", ""],
    ["--name", "."],
    ["--name", "a/b"],
    ["--name", ".hidden"],
]


@pytest.mark.parametrize("name", BAD_NAMES, ids=lambda a: repr(a[1:]))
def test_bundle_refuses_a_name_that_is_not_one_plain_folder(models, runs, tmp_path, name):
    before = {n: files_under(models / n) for n in bundle_names(models)}
    assert set(before) == set(bundle_names(MODELS_DIR))
    argv = [a.replace("{tmp}", str(tmp_path)) for a in name]
    with pytest.raises(ValueError, match=r"^--name = .* is invalid; allowed: a plain bundle name"):
        tools.bundle_main([*argv, "--root", str(models), "--runs", str(runs[0])])
    assert {n: files_under(models / n) for n in bundle_names(models)} == before
    assert sorted(p.name for p in models.iterdir()) == sorted(before), "nothing added"
    assert not (models.parent / "escape").exists() and not (tmp_path / "abs").exists()


def test_bundle_without_name_is_a_one_line_error_with_exit_code_2(models, runs):
    script = Path(sys.executable).with_name("tendon2r-bundle")  # the console entry
    cmd = [str(script)] if script.is_file() else [
        sys.executable, "-c", "from tendon2r_gym.app.tools import bundle; bundle()"]  # fmt: skip
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
    }
    before = files_under(models)
    proc = subprocess.run(
        [*cmd, "--root", str(models), "--runs", str(runs[0])],
        capture_output=True, text=True, env=env,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert (
        proc.stderr.startswith("error: --name = None is invalid") and proc.stderr.count("\n") == 1
    )
    assert files_under(models) == before


def test_replacing_a_bundle_needs_the_flag(tmp_path, runs):
    root = tmp_path / "models"
    bundle_runs([runs[0]], "tiny", "first", root)
    first = files_under(root)
    with pytest.raises(ValueError, match=r"^name = 'tiny' is invalid.*replace=True.*tiny"):
        bundle_runs([runs[1]], "tiny", "second", root)
    with pytest.raises(ValueError, match=r"^--name = 'tiny' is invalid.*--replace to replace"):
        tools.bundle_main(["--name", "tiny", "--root", str(root), "--runs", str(runs[1])])
    with pytest.raises(ValueError, match=r"^--runs = \[\] is invalid"):
        tools.bundle_main(["--name", "new", "--root", str(root)])
    assert files_under(root) == first
    tools.bundle_main(["--name", "tiny", "--replace", "--root", str(root), "--runs", str(runs[1])])
    meta = bundle_meta("tiny", root)
    assert meta["seeds"] == [1] and meta["command"].startswith("tendon2r-bundle --name tiny")
    assert sorted(p.name for p in (root / "tiny").iterdir()) == ["bundle.json", "seed_1"]
    assert sorted(p.name for p in root.iterdir()) == ["tiny"], "no temporary folder is left"
    assert bundled_model("tiny", root=root) == root / "tiny" / "seed_1" / "best_model.zip"


def test_a_folder_that_is_not_a_bundle_is_never_replaced(tmp_path, runs):
    root = tmp_path / "models"
    (root / "notes").mkdir(parents=True)
    (root / "notes" / "keep.txt").write_text("mine")
    with pytest.raises(ValueError, match="not a bundle"):
        bundle_runs([runs[0]], "notes", "cmd", root, replace=True)
    assert files_under(root) == {"notes/keep.txt": b"mine"}


def test_bundling_refuses_a_corrupt_model(tmp_path, runs):
    zip_path = runs[0] / "best_model.zip"
    zip_path.write_bytes(zip_path.read_bytes()[:1000])
    with pytest.raises(ValueError, match="best_model.zip is truncated"):
        bundle_runs([runs[0]], "tiny", "cmd", tmp_path / "models")
    assert not (tmp_path / "models" / "tiny").exists()


@pytest.mark.parametrize("error", [OSError("disk full"), KeyboardInterrupt()])
def test_a_failure_mid_copy_leaves_the_old_bundle_intact(tmp_path, runs, monkeypatch, error):
    root = tmp_path / "models"
    bundle_runs([runs[0]], "tiny", "first", root)
    first = files_under(root)
    copy, calls = shutil.copy2, []

    def failing_copy(src, dst):
        calls.append(src)
        if len(calls) == 3:
            raise error
        return copy(src, dst)

    monkeypatch.setattr(bundle.shutil, "copy2", failing_copy)
    with pytest.raises(type(error)):
        bundle_runs(runs, "tiny", "second", root, replace=True)
    assert len(calls) == 3
    assert files_under(root) == first, "the old bundle is intact, the temporary folder gone"


def test_a_failed_rename_puts_the_old_bundle_back(tmp_path, runs, monkeypatch):
    root = tmp_path / "models"
    bundle_runs([runs[0]], "tiny", "first", root)
    first = files_under(root)
    rename = pathlib.Path.rename

    def failing_rename(self, target):
        if ".new-" in self.name:
            raise OSError("rename failed")
        return rename(self, target)

    monkeypatch.setattr(pathlib.Path, "rename", failing_rename)
    with pytest.raises(OSError, match="rename failed"):
        bundle_runs([runs[1]], "tiny", "second", root, replace=True)
    assert files_under(root) == first


def test_train_checks_its_bundle_name_before_training(monkeypatch):
    def trained(*args):
        raise AssertionError("training started")

    monkeypatch.setattr(cli, "experiment", trained)
    with pytest.raises(ValueError, match=r"^--bundle = '\.\./x' is invalid"):
        cli.train_main(["--bundle", "../x"])
    with pytest.raises(ValueError, match=r"^--bundle = 'default' is invalid.*--replace-bundle"):
        cli.train_main(["--bundle", "default"])  # a bundled model: replaced only when asked
    with pytest.raises(AssertionError, match="training started"):
        cli.train_main(["--bundle", "default", "--replace-bundle"])


# -- B: corrupt model-side files --------------------------------------------------------------
@pytest.fixture
def small(tmp_path) -> Path:
    """A copy of a small bundle: its primary seed and bundle.json."""
    root = tmp_path / "models"
    shutil.copytree(MODELS_DIR / SMALL, root / SMALL)
    return root


def truncate(fraction):
    def cut(path: Path) -> None:
        data = path.read_bytes()
        path.write_bytes(data[: int(len(data) * fraction)])

    return cut


def no_model(path: Path) -> None:
    path.unlink()
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("notes.txt", "no model here")


def swapped(path: Path) -> None:
    shutil.copy(MODELS_DIR / OTHER / "seed_0" / path.name, path)


def without_array(path: Path) -> None:
    import numpy as np

    with np.load(path) as npz:
        arrays = {k: npz[k] for k in npz.files if k != "obs_var"}
    with open(path, "wb") as f:
        np.savez(f, **arrays)


CORRUPT = {
    "zip cut at 50%": ("best_model.zip", truncate(0.5), "is truncated"),
    "zip cut at 99.9%": ("best_model.zip", truncate(0.999), "is truncated"),
    "zip without a model": ("best_model.zip", no_model, "is not an SB3 model zip"),
    "zip of another bundle": ("best_model.zip", swapped,
                              r"does not match .*observation shape \(26,\) in the file, \(24,\)"),
    "npz cut at 50%": ("best_model_vecnormalize.npz", truncate(0.5), "is truncated"),
    "empty npz": ("best_model_vecnormalize.npz", truncate(0), "is truncated"),
    "npz not a zip": ("best_model_vecnormalize.npz", lambda p: p.write_text("stats"),
                      "is not a statistics npz"),
    "npz without an array": ("best_model_vecnormalize.npz", without_array,
                             "is not a statistics npz of this version .no array 'obs_var'"),
    "npz of another bundle": ("best_model_vecnormalize.npz", swapped,
                              r"does not match .*observation shape \(26,\) in the file, \(24,\)"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(CORRUPT))
def test_a_corrupt_model_file_is_one_error_naming_it(small, case):
    name, damage, what = CORRUPT[case]
    path = small / SMALL / "seed_0" / name
    env = gym.make("Tendon2R-v0", preset="default")
    PPOPolicy.load(path.with_name("best_model.zip"), env)  # whole, it loads
    damage(path)
    with pytest.raises(ValueError, match=what) as err:
        PPOPolicy.load(path.with_name("best_model.zip"), env)
    assert str(path) in str(err.value) and "to recover: re-bundle it" in str(err.value)
    # tendon2r-evaluate's --model (and a fine-tune's --init-from, through trained_model).
    with pytest.raises(ValueError, match=what):
        cli.evaluate_main(["--policy", "ppo", "--model", str(path.with_name("best_model.zip")),
                           "--episodes", "1"])  # fmt: skip


def test_the_loaders_name_the_file(small):
    from stable_baselines3.common.vec_env import DummyVecEnv

    folder = small / SMALL / "seed_0"
    other = DummyVecEnv([lambda: gym.make("Tendon2R-v0", preset="default", preview_steps=2)])
    with pytest.raises(ValueError, match=r"best_model.zip does not match .*observation shape"):
        load_ppo(folder / "best_model.zip", other, {})
    with pytest.raises(PickleRefused, match=r"best_model.zip is read by SB3.*--trust-pickle"):
        load_model(folder / "best_model.zip", device="cpu")  # SB3's load unpickles
    with pytest.raises(ValueError, match=r"best_model.zip does not load \(ValueError: Observ"):
        load_model(folder / "best_model.zip", env=other, device="cpu", trust_pickle=True)
    truncate(0.5)(folder / "best_model.zip")
    for load in (load_policy, lambda p: load_model(p, trust_pickle=True, device="cpu")):
        with pytest.raises(ValueError, match="best_model.zip is truncated"):
            load(folder / "best_model.zip")
    swapped(folder / "best_model_vecnormalize.npz")
    venv = DummyVecEnv([lambda: gym.make("Tendon2R-v0", preset="default")])
    with pytest.raises(ValueError, match=r"vecnormalize.npz does not match .*\(26,\).*\(24,\)"):
        load_vecnormalize(folder / "best_model_vecnormalize.npz", venv)


BUNDLE_JSON = {
    "not JSON": ("{garbage", "is not JSON"),
    "binary": (b"\xff\xfe\x00", "is not JSON"),
    "a list": ("[0, 1]", "is not a JSON object"),
    "missing a key": (json.dumps({"seeds": [0], "train_command": "", "command": ""}),
                      "is missing key 'primary_seed'"),
    "bad seeds": (json.dumps({"seeds": "0", "primary_seed": 0, "train_command": "",
                              "command": ""}), "seeds = '0' is not a list"),
    "primary not a seed": (json.dumps({"seeds": [0], "primary_seed": 3, "train_command": "",
                                       "command": ""}), "primary_seed = 3 is not among"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(BUNDLE_JSON))
def test_a_corrupt_bundle_json_is_one_error_naming_it(small, case):
    text, what = BUNDLE_JSON[case]
    path = small / SMALL / "bundle.json"
    (path.write_bytes if isinstance(text, bytes) else path.write_text)(text)
    for read in (lambda: bundle_meta(SMALL, small), lambda: bundled_model(SMALL, root=small)):
        with pytest.raises(ValueError, match=what) as err:
            read()
        assert str(path) in str(err.value) and "tendon2r-bundle --name default --replace" in str(
            err.value
        )
