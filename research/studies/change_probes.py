"""What research.studies.change_costs runs in a fresh process on an edited copy of the
repository: each kind's use as a user would make it, and the fingerprint of what an
off-by-default change must leave as it was.

    python research/studies/change_probes.py ROOT fingerprint [PROBE ...]   # JSON on stdout

ROOT is the edited copy, which must also be the first entry of PYTHONPATH (so that
``tendon2r_gym`` is imported from it, and checked to be).  Each PROBE (a name of
``PROBES``) adds its checks, ``{"check", "ok", "detail"}``; an exception ends a probe
as a failed check.
"""

from __future__ import annotations

import hashlib
import json
import sys
import traceback
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

#: Control steps of every rollout a probe compares.
STEPS = 20
#: The registered id the probes make (its defaults: the env a new user gets).
ENV_ID = "Tendon2R-v1"
#: The presets whose compiled models the fingerprint holds: the ideal arm and real cables.
FINGERPRINT_PRESETS = ("default", "real_arm")


class Checks:
    """The checks of one run, in order."""

    def __init__(self) -> None:
        self.rows: list[dict[str, Any]] = []

    def __call__(self, name: str, ok: Any, detail: Any = "") -> bool:
        self.rows.append({"check": name, "ok": bool(ok), "detail": str(detail)})
        return bool(ok)


# -- rollouts ------------------------------------------------------------------------------------
def _make(**kwargs: Any) -> Any:
    import gymnasium as gym

    import tendon2r_gym  # noqa: F401  (registers the ids)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return gym.make(ENV_ID, **kwargs)


def actions(n_actions: int, steps: int = STEPS) -> np.ndarray:
    """Returns (steps, n_actions) float32 commands: a slow sweep of part of the range."""
    k = np.arange(steps)[:, None]
    return (0.3 * np.sin(0.1 * k + np.arange(n_actions))).astype(np.float32)


def single(seed: int = 0, **kwargs: Any) -> tuple[np.ndarray, np.ndarray, list[dict]]:
    """Returns the observations (STEPS + 1, n), rewards (STEPS,) and step infos of one env of
    ENV_ID with ``kwargs``, reset with ``seed``."""
    env = _make(**kwargs)
    obs, _ = env.reset(seed=seed)
    seen, rewards, infos = [obs], [], []
    for a in actions(env.action_space.shape[0]):
        obs, reward, terminated, truncated, info = env.step(a)
        seen.append(obs)
        rewards.append(reward)
        infos.append(info)
    env.close()
    return np.array(seen), np.array(rewards), infos


def vector(n: int = 2, seed: int = 0, **kwargs: Any) -> tuple[np.ndarray, np.ndarray]:
    """Returns the observations (STEPS + 1, n, obs) and rewards (STEPS, n) of ENV_ID's native
    vector env of ``n`` arms with ``kwargs``, reset with ``seed`` (arm i: seed + i)."""
    import gymnasium as gym

    import tendon2r_gym  # noqa: F401

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)
    obs, _ = env.reset(seed=seed)
    seen, rewards = [obs], []
    for a in actions(env.single_action_space.shape[0]):
        obs, reward, *_ = env.step(np.tile(a, (n, 1)))
        seen.append(obs)
        rewards.append(reward)
    env.close()
    return np.array(seen), np.array(rewards)


def agree(check: Checks, name: str, n: int = 2, **kwargs: Any) -> bool:
    """Checks that ENV_ID's single envs (seeds 0 .. n - 1) and its native vector env (seed 0)
    give the same observations and rewards, bit for bit."""
    obs, rewards = vector(n, **kwargs)
    same = True
    for i in range(n):
        one_obs, one_rewards, _ = single(seed=i, **kwargs)
        same &= np.array_equal(one_obs, obs[:, i]) and np.array_equal(one_rewards, rewards[:, i])
    return check(name, same, f"{n} arms, {STEPS} steps, observations and rewards")


def digest(*arrays: np.ndarray) -> str:
    """Returns the SHA-256 (12 hex digits) of the arrays' bytes."""
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:12]


def model_digest(model: Any) -> str:
    """Returns the digest of a compiled MjModel's binary (mj_saveModel): every array."""
    import mujoco

    buf = np.zeros(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, buf)
    return digest(buf)


def _motion(model: Any, steps: int = 200) -> np.ndarray:
    """Returns the joint angles of ``model`` after each of ``steps`` steps from rest, every
    motor at a third of its command."""
    import mujoco

    data = mujoco.MjData(model)
    data.ctrl[:] = 1.0 / 3.0
    out = []
    for _ in range(steps):
        mujoco.mj_step(model, data)
        out.append(data.qpos[:2].copy())
    return np.array(out)


def raises(make: Callable[[], Any], field: str) -> tuple[bool, str]:
    """Returns whether ``make()`` raises a ValueError that names ``field``, and its text."""
    try:
        make()
    except ValueError as e:
        return field in str(e), str(e).splitlines()[0]
    return False, "no error"


def fingerprint() -> dict[str, Any]:
    """Returns what an off-by-default change must keep: digests of ENV_ID's single-env and
    vector-env rollouts and of the compiled models of FINGERPRINT_PRESETS, and every
    registered id's contract paths that changed from its pinned contract (a contract may
    grow: tendon2r_gym.envs.contract.changes)."""
    import re

    import gymnasium as gym

    from tendon2r_gym.envs.contract import changes, env_contract, pinned, pinned_contract
    from tendon2r_gym.envs.env_config import EnvConfig
    from tendon2r_gym.simulation.model import build_model

    obs, rewards, _ = single()
    vobs, vrewards = vector()
    ids = sorted(i for i in gym.registry if re.fullmatch(r"Tendon2R(Residual)?-v\d+", i))
    return {
        "single": digest(obs, rewards),
        "vector": digest(vobs, vrewards),
        "models": {
            p: model_digest(build_model(EnvConfig.make(p).mechanism)) for p in FINGERPRINT_PRESETS
        },
        "contracts": {
            i: changes(pinned_contract(i), json.loads(json.dumps(env_contract(i)))) for i in ids
        },
        "pinned": dict(pinned()),
    }


# -- the kinds' probes ----------------------------------------------------------------------------
def observation(check: Checks, root: Path) -> None:
    """observe ``reference_acceleration``: the reference's acceleration ``ddq_des``."""
    from tendon2r_gym.task import observation as L
    from tendon2r_gym.task.reference import Reference

    check("observe may list it", "reference_acceleration" in L.OBSERVABLE, L.OBSERVABLE)
    base = _make().observation_space.shape[0]
    env = _make(observe=["error_rate", "reference_acceleration"])
    n = env.observation_space.shape[0]
    check("the observation grows by the entry's size", n == base + 2, f"{base} -> {n}")
    every = ["error_rate", "feedforward", "reference_acceleration", "force_limit"]
    env = _make(observe=every)
    layout = env.unwrapped.config.observation.layout()
    start = 0
    for name, size in layout:
        if name == "ddq_des":
            break
        start += size
    where = slice(start, start + 2)
    check("the layout names it, size 2", ["ddq_des", 2] in layout, layout)
    obs, info = env.reset(seed=3)
    ref = Reference.from_dict(info["reference"])
    worst = 0.0
    for a in actions(env.action_space.shape[0]):
        obs, _, _, _, info = env.step(a)
        want = ref.qddot(info["time"])
        worst = max(worst, float(np.max(np.abs(obs[where] - want) / (1.0 + np.abs(want)))))
    check("its values are the reference's acceleration", worst < 1e-12, f"max error {worst:.1e}")
    agree(check, "single and vector env agree with it observed", observe=every)
    ok, text = raises(lambda: _make(observe=["no_such_entry"]), "observe")
    check("an unknown name is still refused, naming observe", ok, text)


def reward(check: Checks, root: Path) -> None:
    """The reward term ``tracking_abs``, -sum(|e|) in deg, weight 0."""
    from tendon2r_gym.task.rewards import REWARD_SCALES

    check("its default weight is 0", REWARD_SCALES.get("tracking_abs") == 0.0, REWARD_SCALES)
    scales = {"tracking_abs": 1.0}
    _, rewards, infos = single(reward_scales=scales)
    check("info has reward_tracking_abs", all("reward_tracking_abs" in i for i in infos))
    worst = max(
        abs(i["reward_tracking_abs"] + float(np.sum(np.abs(i["tracking_error_deg"]))))
        for i in infos
    )
    check("it is -sum(|e|) in deg", worst < 1e-9, f"max error {worst:.1e}")
    sums = [sum(v for k, v in i.items() if k.startswith("reward_")) for i in infos]
    check("the reward is the sum of the terms, exactly", sums == rewards.tolist())
    agree(check, "single and vector env agree with it weighted", reward_scales=scales)


def baseline(check: Checks, root: Path) -> None:
    """The baseline ``pdv``: PD without the reference-velocity feed-forward."""
    from tendon2r_gym.evaluation.evaluator import BASELINE, evaluate, names

    check("the registry lists it as a baseline", "pdv" in names(BASELINE), names(BASELINE))
    metrics, _ = evaluate("pdv", {}, [0])
    pd, _ = evaluate("pd", {}, [0])
    finite = bool(np.all(np.isfinite(metrics["rms_deg"]))) and metrics["diverged_episodes"] == 0
    check("evaluate('pdv', {}, [0]) runs", finite, f"RMS {metrics['rms_deg']} deg")
    check("it is not PD", metrics["rms_deg"] != pd["rms_deg"], f"PD RMS {pd['rms_deg']} deg")


def mechanism(check: Checks, root: Path) -> None:
    """The Mechanism field ``tip_mass``: a payload at the effector (kg)."""
    import tempfile

    import mujoco

    from tendon2r_gym.simulation.mechanism import Mechanism
    from tendon2r_gym.simulation.model import build_model

    bare, loaded = build_model(Mechanism()), build_model(Mechanism(tip_mass=0.01))
    b = mujoco.mj_name2id(bare, mujoco.mjtObj.mjOBJ_BODY, "link_b")
    added = float(loaded.body_mass[b] - bare.body_mass[b])
    check("link b is 0.01 kg heavier", abs(added - 0.01) < 1e-12, f"{added:.15g} kg")
    import yaml

    from tendon2r_gym.presets import preset_path

    experiment = yaml.safe_load(preset_path("default").read_text())
    experiment["mechanism"]["tip_mass"] = 0.01
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "arm.yaml"
        path.write_text(yaml.safe_dump(experiment))
        env = _make(preset=str(path))
        got = env.unwrapped.config.mechanism.tip_mass
    check("an experiment file sets it by name", got == 0.01, got)
    default_force = _make().unwrapped.config.mechanism.max_tendon_force
    force = env.unwrapped.config.mechanism.max_tendon_force
    check("the auto force limit grows with the payload", force > default_force,
          f"{default_force} -> {force} N")  # fmt: skip
    _, rewards, infos = single(mechanism={"tip_mass": 0.01})
    check("the env steps with it", not any(i["diverged"] for i in infos), f"{STEPS} steps")
    ok, text = raises(lambda: Mechanism(tip_mass=-1.0), "Mechanism.tip_mass")
    check("a bad value names Mechanism.tip_mass", ok, text)


def routing(check: Checks, root: Path) -> None:
    """The routing ``n_plus_1_mirrored``: n_plus_1 with every side flipped, pull-only."""
    from tendon2r_gym.evaluation.evaluator import evaluate
    from tendon2r_gym.simulation.mechanism import Mechanism

    arm = {"routing": "n_plus_1_mirrored", "pull_only": True}
    check("a pull-only Mechanism takes it", Mechanism(**arm).n_tendons == 3)
    env = _make(mechanism=arm)
    check("the env has 3 motors", env.action_space.shape == (3,), env.action_space)
    _, _, infos = single(mechanism=arm)
    check("the env steps", not any(i["diverged"] for i in infos), f"{STEPS} steps")
    metrics, _ = evaluate("pd", {"mechanism": arm}, [0])
    ok = bool(np.all(np.isfinite(metrics["rms_deg"]))) and metrics["diverged_episodes"] == 0
    check("PD tracks on it", ok, f"RMS {metrics['rms_deg']} deg")


def preset(check: Checks, root: Path) -> None:
    """The preset ``slow_reference``: the default arm on a 1 Hz / 1.2 Hz reference."""
    from tendon2r_gym.evaluation.evaluator import evaluate
    from tendon2r_gym.presets import list_presets

    check("list_presets has it", "slow_reference" in list_presets(), list_presets())
    ref = _make(preset="slow_reference").unwrapped.config.reference.to_dict()
    check("gym.make(preset=...) reads it", ref["freq_hz"] == [1.0, 1.2], ref["freq_hz"])
    metrics, _ = evaluate("pd", {"preset": "slow_reference"}, [0])
    ok = bool(np.all(np.isfinite(metrics["rms_deg"]))) and metrics["diverged_episodes"] == 0
    check("PD runs on it", ok, f"RMS {metrics['rms_deg']} deg")


def _realism_field(check: Checks, name: str, on: float, bad: float) -> None:
    """The checks every realism field gets: validated, in ``realistic``, out of ``ideal()``."""
    from tendon2r_gym.simulation.mechanism import Mechanism

    mech = Mechanism(**{name: on})
    check("it counts as realism, and ideal() leaves it out",
          mech.realistic and getattr(mech.ideal(), name) == 0.0)  # fmt: skip
    ok, text = raises(lambda: Mechanism(**{name: bad}), f"Mechanism.{name}")
    check(f"a bad value names Mechanism.{name}", ok, text)


def realism_model(check: Checks, root: Path) -> None:
    """The realism field ``joint_friction``: the joints' dry friction, MuJoCo's frictionloss."""
    import mujoco

    from tendon2r_gym.simulation.mechanism import Mechanism
    from tendon2r_gym.simulation.model import build_model, to_xml

    mech = Mechanism(joint_friction=1e-4)
    model = build_model(mech)
    check("the compiled joints have it", np.all(model.dof_frictionloss[:2] == 1e-4),
          model.dof_frictionloss[:2])  # fmt: skip
    exported = mujoco.MjModel.from_xml_string(to_xml(mech))
    same = np.array_equal(exported.dof_frictionloss, model.dof_frictionloss)
    check("tendon2r-export writes it (the XML's model moves the same, bit for bit)",
          same and np.array_equal(_motion(exported), _motion(model)))  # fmt: skip
    on, _, _ = single(mechanism={"joint_friction": 1e-4})
    off, _, _ = single()
    check("it changes the motion", not np.array_equal(on, off))
    agree(check, "single and vector env agree with it on", mechanism={"joint_friction": 1e-4})
    _realism_field(check, "joint_friction", 1e-4, -1.0)


def realism_step(check: Checks, root: Path) -> None:
    """The realism field ``motor_offset``: the drivers' zero error, added to every command
    between the action and ctrl, in both envs."""
    from tendon2r_gym.app.tools import export_note
    from tendon2r_gym.envs.env_config import EnvConfig

    arm = {"motor_offset": 0.05}
    env = _make(mechanism=arm)
    env.reset(seed=0)
    a = np.array([0.25, -0.5], dtype=np.float32)
    env.step(a)
    ctrl = env.unwrapped.data.ctrl.tolist()
    want = [x + 0.05 for x in a.tolist()]
    check("ctrl is the command plus the offset, exactly", ctrl == want, f"{ctrl} vs {want}")
    on, _, _ = single(mechanism=arm)
    off, _, _ = single()
    check("it changes the motion", not np.array_equal(on, off))
    same = "single and vector env agree with it on"
    agree(check, f"{same} (default arm)", mechanism=arm)
    agree(check, f"{same} (joint-torque mode)", mechanism=arm, action_mode="joint_torque")
    agree(check, f"{same} (real_arm: delay, lag, sensors)", preset="real_arm", mechanism=arm)
    note = export_note(EnvConfig.make(mechanism=arm), "x")
    check("tendon2r-export lists it as done in Python", "motor_offset" in note)
    _realism_field(check, "motor_offset", 0.05, 2.0)


#: The copied bundle and the bundle it copies (change_costs's ``promote`` kind).
PROMOTED, ORIGINAL = "random_reference_copy", "random_reference"


def promote(check: Checks, root: Path) -> None:
    """The bundle ``random_reference_copy``, registered in shipped.yaml."""
    from tendon2r_gym.artifacts.bundle import bundle_meta, bundle_names, bundled_model
    from tendon2r_gym.artifacts.registry import shipped
    from tendon2r_gym.artifacts.runs import RunFolder, stem_of
    from tendon2r_gym.envs.contract import contract_hash
    from tendon2r_gym.envs.registration import make
    from tendon2r_gym.policies.learned import PPOPolicy
    from tendon2r_gym.training import Hyperparams

    lines = shipped()
    check("shipped() lists it", PROMOTED in lines, list(lines))
    check("bundle_names() lists it", PROMOTED in bundle_names())
    line = lines[PROMOTED]
    meta = bundle_meta(PROMOTED)
    check("its line's seeds are the bundle's", list(line.seeds) == meta["seeds"])
    record = RunFolder(stem_of(bundled_model(PROMOTED)).parent).read_json("run.json")
    check("its line's contract is its run's", contract_hash(record["env_config"]) == line.contract)
    env = make(**Hyperparams.from_entry(line.entry).env_kwargs)
    obs, _ = env.reset(seed=0)
    policy = PPOPolicy.load(bundled_model(PROMOTED), env)
    original = PPOPolicy.load(bundled_model(ORIGINAL), env)
    action, _ = policy.predict(obs)
    same = np.array_equal(action, original.predict(obs)[0])
    check("bundled_model loads through PPOPolicy.load", same, f"action {action}")
    models_page = (root / "docs" / "models.md").read_text()
    check("the models page has its card", PROMOTED in models_page)
    ran = _benchmark_bundles()
    check("tendon2r-benchmark runs it", PROMOTED in ran, f"it runs the bundles {ran}")


def _benchmark_bundles() -> list[str]:
    """Returns the bundles whose models tendon2r-benchmark (benchmark_bundled) evaluates: a
    dry run, its evaluations and report replaced by stubs."""
    import tempfile

    from tendon2r_gym.app import benchmark

    seen: list[str] = []

    def evaluate(policy, env_kwargs, seeds, model=None, options=None, jitter=None):
        if model is not None:
            seen.append(Path(model).as_posix())
        # stub figures > 0: the rows' statistics divide by PD's
        return {"policy": policy, "rms_deg": [1.0, 1.0], "max_deg": [1.0, 1.0]}, [None]

    benchmark.evaluate = evaluate
    benchmark.jittered_rms = lambda *a, **k: [[1.0, 1.0]]
    benchmark.plot_trace = lambda *a, **k: None
    benchmark.report.bundled_page = lambda result: []
    benchmark._write = lambda out, result, lines: result
    with tempfile.TemporaryDirectory() as tmp:
        benchmark.benchmark_bundled(1, Path(tmp), "dry run")
    return sorted({Path(m).parent.parent.name for m in seen})  # <bundle>/seed_<n>/<file>


PROBES: dict[str, Callable[[Checks, Path], None]] = {
    f.__name__: f
    for f in (observation, reward, baseline, mechanism, routing, preset, realism_model,
              realism_step, promote)
}  # fmt: skip


def run(root: Path, names: list[str]) -> dict[str, Any]:
    """Returns {"fingerprint": ..., "checks": [...]} for ``names`` ("fingerprint" or PROBES)."""
    import tendon2r_gym

    where = Path(tendon2r_gym.__file__).resolve()
    if not where.is_relative_to(root.resolve()):
        raise RuntimeError(f"tendon2r_gym was imported from {where}, not from {root}")
    out: dict[str, Any] = {"checks": []}
    for name in names:
        if name == "fingerprint":
            out["fingerprint"] = fingerprint()
            continue
        check = Checks()
        try:
            PROBES[name](check, root)
        except Exception as e:  # the probe's own failure is its result
            check("the probe ran to its end", False, f"{type(e).__name__}: {e}")
            traceback.print_exc()
        out["checks"] += check.rows
    return out


if __name__ == "__main__":
    import contextlib

    here = Path(__file__).resolve().parent
    sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != here]  # no study shadows
    with contextlib.redirect_stdout(sys.stderr):  # stdout holds the JSON alone
        result = run(Path(sys.argv[1]), sys.argv[2:])
    print(json.dumps(result))
