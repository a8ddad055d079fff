"""Ordinary PPO clients on the registered ids: what a user's own settings learn.

    python -m research.studies.clients --steps 300000 --seeds 0 1 2         # results/clients.*
    python -m research.studies.clients --settings Tendon2RResidual-v2 --clients project \
        --seeds 0 --residual-steps 3500000 --eval-every 250000           # the project's entry
    python -m research.studies.clients --only-report                    # the page, from the runs
    python -m research.studies.clients --steps 4096 --eval-every 2048 --seeds 0 --out x  # smoke

Each client is a PPO setting a user brings from elsewhere, applied to ``gym.make(env_id)`` with
the id's own defaults and nothing else changed:

- ``sb3``: ``PPO("MlpPolicy", env)`` with SB3's default arguments, in ``VecNormalize``
  (rl_zoo3's MuJoCo defaults: ``normalize: true``);
- ``sb3_raw``: ``PPO("MlpPolicy", env)`` with no argument changed and no normalization;
- ``zoo_reacher``: rl_zoo3's shipped ``Reacher-v2`` entry (read from the installed
  ``hyperparams/ppo.yml``), with its VecNormalize (gamma of the entry), as ``rl_zoo3.train``
  builds it;
- ``cleanrl``: CleanRL's ``ppo_continuous_action.py`` defaults (CleanRL is a script, not a
  package): SB3's defaults with the learning rate annealed linearly to 0, observations and
  rewards normalized and clipped at 10;
- ``zoo_reacher_gamma_0.99``: the same entry with SB3's default discount (a diagnosis: is
  the entry's 10-step horizon what fails?);
- ``project``: the project's own entry for the id in ``configs/rl_zoo3/ppo.yml`` (what
  ``rl_zoo3.train --conf-file configs/rl_zoo3/ppo.yml`` trains), for an id whose entry keeps
  the id's defaults (``Tendon2RResidual-v2``: the residual recipe's PPO settings).

Every run evaluates its policy deterministically every ``--eval-every`` steps and at the end,
on the eval seeds, beside PD on the same episodes.  One result file per run under
``<out>/clients_runs/``: a rerun skips the runs that are there (a killed study continues).
"""

from __future__ import annotations

import importlib.resources
import json
import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import yaml

from research.studies import joints, one_or_more, save_json
from tendon2r_gym.app.args import arg, parse

CLIENTS: dict[str, str] = {
    "sb3": "SB3 PPO defaults, VecNormalize (rl_zoo3's MuJoCo defaults)",
    "sb3_raw": "SB3 PPO defaults, no normalization",
    "zoo_reacher": "rl_zoo3's Reacher-v2 entry (gamma 0.9, n_steps 512, batch 32)",
    "cleanrl": "CleanRL ppo_continuous_action defaults (in SB3)",
    "project": "the project's own entry for the id (configs/rl_zoo3/ppo.yml)",
    "zoo_reacher_gamma_0.99": "rl_zoo3's Reacher-v2 entry with gamma 0.99 (a diagnosis)",
}
#: The project's rl_zoo3 file (the ``project`` client's settings).
PROJECT_ZOO_FILE = Path(__file__).resolve().parents[2] / "configs" / "rl_zoo3" / "ppo.yml"
ZOO_ENTRY = "Reacher-v2"
#: What a client trains on: a name -> (registered id, env kwargs over the id's defaults).  The
#: ids themselves (no kwargs) are what a user gets; the others change one factor of v1 at a
#: time, for the diagnosis (why ordinary settings fail on v1).
SETTINGS: dict[str, tuple[str, dict[str, Any]]] = {
    "Tendon2R-v2": ("Tendon2R-v2", {}),
    "Tendon2RResidual-v2": ("Tendon2RResidual-v2", {}),
    "Tendon2R-v1": ("Tendon2R-v1", {}),
    "v1 action_rate 0": ("Tendon2R-v1", {"reward_scales": {"action_rate": 0.0}}),
    "v1 action_rate 0.01": ("Tendon2R-v1", {"reward_scales": {"action_rate": 0.01}}),
    "v1 filter 2 ms": ("Tendon2R-v1", {"action_filter_tau": 0.002}),
    "v1 tracking_rate 1": ("Tendon2R-v1", {"reward_scales": {"tracking_rate": 1.0}}),
    "v1 ctrl_dt 5 ms": ("Tendon2R-v1", {"ctrl_dt": 0.005}),
}
#: Entries of a zoo hyperparameter entry that are not PPO keyword arguments.
ZOO_ONLY = ("normalize", "n_envs", "policy", "n_timesteps", "env_wrapper", "frame_stack")


def zoo_reacher() -> dict[str, Any]:
    """Returns rl_zoo3's shipped Reacher-v2 entry (its installed hyperparams/ppo.yml)."""
    path = Path(str(importlib.resources.files("rl_zoo3") / "hyperparams" / "ppo.yml"))
    return dict(yaml.safe_load(path.read_text())[ZOO_ENTRY])


def project_entry(setting: str) -> dict[str, Any]:
    """Returns the project's rl_zoo3 entry for a setting's id; a ValueError unless the setting
    is the id itself and the entry trains on the id's defaults (no wrapper, the default arm)."""
    env_id, kwargs = SETTINGS[setting]
    entry = yaml.safe_load(PROJECT_ZOO_FILE.read_text()).get(env_id)
    if (
        kwargs
        or entry is None
        or "env_wrapper" in entry
        or entry["env_kwargs"] != {"preset": "default"}
    ):
        raise ValueError(
            f"--clients project is invalid on {setting!r}; allowed: a setting that is an id "
            "whose project entry keeps its defaults (Tendon2RResidual-v2)"
        )
    return entry


def client_settings(
    client: str, setting: str = "Tendon2R-v2"
) -> tuple[dict[str, Any], dict[str, Any] | None, int]:
    """Returns (PPO keyword arguments, VecNormalize keyword arguments or None, n_envs) of a
    client on a setting."""
    if client == "sb3":
        return {}, {}, 1
    if client == "sb3_raw":
        return {}, None, 1
    if client == "cleanrl":
        return {"learning_rate": _linear(3e-4)}, {"clip_obs": 10.0, "clip_reward": 10.0}, 1
    if client in ("zoo_reacher", "zoo_reacher_gamma_0.99", "project"):
        entry = project_entry(setting) if client == "project" else zoo_reacher()
        if client == "zoo_reacher_gamma_0.99":
            entry["gamma"] = 0.99
        ppo = {k: v for k, v in entry.items() if k not in (*ZOO_ONLY, "env_kwargs")}
        if isinstance(ppo.get("learning_rate"), str):  # rl_zoo3's "lin_<start>"
            ppo["learning_rate"] = _linear(float(ppo["learning_rate"].removeprefix("lin_")))
        n_envs = int(entry.get("n_envs", 1))
        norm = entry.get("normalize", False)
        if not norm:
            return ppo, None, n_envs
        norm = {"gamma": ppo.get("gamma", 0.99), **(norm if isinstance(norm, dict) else {})}
        return ppo, norm, n_envs
    raise ValueError(f"client {client!r} is invalid; allowed: {list(CLIENTS)}")


class _Linear:
    """A learning rate decaying linearly to 0 (a picklable SB3 schedule)."""

    def __init__(self, start: float) -> None:
        self.start = start

    def __call__(self, progress_remaining: float) -> float:
        return self.start * progress_remaining


def _linear(start: float) -> _Linear:
    return _Linear(start)


class Trained:
    """A trained SB3 model as a deterministic ``predict`` policy on raw observations (its
    VecNormalize statistics applied, if any)."""

    def __init__(self, model: Any, vecnorm: Any = None) -> None:
        self.model, self.vecnorm = model, vecnorm

    def predict(self, observation: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:  # fmt: skip
        obs = observation if self.vecnorm is None else self.vecnorm.normalize_obs(observation)
        action, _ = self.model.predict(obs, deterministic=True)
        return action, state


def make(setting: str) -> Any:
    """Returns ``gym.make`` of a setting (SETTINGS): its id with its kwargs."""
    import gymnasium as gym

    import tendon2r_gym  # noqa: F401  (registers the ids)

    env_id, kwargs = SETTINGS[setting]
    return gym.make(env_id, **kwargs)


def evaluate(policy: Any, setting: str, seeds: list[int]) -> dict[str, Any]:
    """Returns the tracking metrics of ``policy`` on a setting's episodes of ``seeds``."""
    from tendon2r_gym.evaluation.metrics import tracking_metrics
    from tendon2r_gym.evaluation.rollout import rollout

    env = make(setting)
    try:
        return tracking_metrics([rollout(policy, env, s) for s in seeds])
    finally:
        env.close()


def pd_metrics(setting: str, seeds: list[int]) -> dict[str, Any]:
    """Returns PD's tracking metrics on a setting's episodes: on a residual id, the zero
    correction (PD's own command); on a plain id, PDPolicy."""
    from tendon2r_gym.policies.baselines import PDPolicy

    env = make(setting)
    try:
        n = env.action_space.shape[0]
        if "Residual" in SETTINGS[setting][0]:
            zero = np.zeros(n, dtype=np.float32)

            class _Zero:
                def predict(self, obs: Any, *args: Any, **kwargs: Any) -> tuple[Any, None]:
                    return zero, None

            return evaluate(_Zero(), setting, seeds)
        return evaluate(PDPolicy.from_env(env), setting, seeds)
    finally:
        env.close()


def summary(metrics: dict[str, Any]) -> dict[str, Any]:
    """Returns the figures a row keeps of tracking metrics."""
    keys = ("rms_deg", "settled_rms_deg", "rms_tension_N", "rms_tension_rate_N_per_s",
            "diverged_episodes")  # fmt: skip
    return {k: metrics[k] for k in keys}


def train_one(setting: str, client: str, seed: int, steps: int, eval_every: int,
              eval_seeds: list[int], out: Path) -> dict[str, Any]:  # fmt: skip
    """Trains one client on one setting with one seed (one torch thread), evaluating as it
    goes; writes and returns the run's result."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    from tendon2r_gym.llvm import load_triton

    load_triton()  # before torch (tendon2r_gym.llvm)
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    import tendon2r_gym  # noqa: F401  (registers the ids)

    torch.set_num_threads(1)
    ppo_kwargs, norm, n_envs = client_settings(client, setting)
    venv: Any = DummyVecEnv([lambda: make(setting)] * n_envs)
    if norm is not None:
        venv = VecNormalize(venv, **norm)
    model = PPO("MlpPolicy", venv, seed=seed, verbose=0, device="cpu", **ppo_kwargs)
    pd = summary(pd_metrics(setting, eval_seeds))
    evaluations: list[dict[str, Any]] = []

    def evaluate_now() -> None:
        vecnorm = venv if norm is not None else None
        row = summary(evaluate(Trained(model, vecnorm), setting, eval_seeds))
        row["steps"] = int(model.num_timesteps)
        row["beats_pd"] = all(p <= d for p, d in zip(row["rms_deg"], pd["rms_deg"], strict=True))
        evaluations.append(row)
        partial = run_path(out, setting, client, seed, steps).with_suffix(".partial")
        partial.parent.mkdir(parents=True, exist_ok=True)  # a run cut off keeps its evaluations
        partial.write_text(json.dumps({"pd": pd, "evaluations": evaluations}, indent=1))

    class Every(BaseCallback):
        next_eval = eval_every

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.next_eval:  # n_envs steps at a time
                evaluate_now()
                self.next_eval += eval_every
            return True

    start = time.perf_counter()
    model.learn(steps, callback=Every())
    wall = time.perf_counter() - start
    if not evaluations or evaluations[-1]["steps"] != model.num_timesteps:
        evaluate_now()
    first = next((e["steps"] for e in evaluations if e["beats_pd"]), None)
    result = {
        "setting": setting, "client": client, "seed": seed, "steps": steps,
        "final": evaluations[-1], "first_beats_pd_steps": first, "pd": pd,
        "evaluations": evaluations, "train_wall_s": wall,
    }  # fmt: skip
    path = run_path(out, setting, client, seed, steps)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(result, indent=1))
    tmp.replace(path)
    path.with_suffix(".partial").unlink(missing_ok=True)
    return result


def run_path(out: Path, setting: str, client: str, seed: int, steps: int) -> Path:
    """Returns the result file of one run."""
    folder = out / "clients_runs" / setting.replace(" ", "_") / client
    return folder / f"seed_{seed}_steps_{steps}.json"


@dataclass
class Args:
    """What ordinary PPO settings learn on each id (module docstring)."""

    settings: Annotated[list[str], arg(f"what to train on, of {list(SETTINGS)}")] = field(
        default_factory=lambda: ["Tendon2R-v2", "Tendon2RResidual-v2"]
    )
    clients: Annotated[list[str], arg(f"clients, of {list(CLIENTS)}")] = field(
        default_factory=lambda: ["sb3", "zoo_reacher", "cleanrl"]
    )
    seeds: Annotated[list[int], arg("training seeds")] = field(default_factory=lambda: [0, 1, 2])
    steps: Annotated[int, arg("env steps per run (plain ids)")] = 1_000_000
    residual_steps: Annotated[int, arg("env steps per run on a residual id")] = 300_000
    eval_every: Annotated[int, arg("env steps between evaluations")] = 50_000
    eval_seeds: Annotated[list[int], arg("evaluation episodes' seeds")] = field(
        default_factory=lambda: [10000, 10001, 10002]
    )
    workers: Annotated[int, arg("runs at once, one process and one torch thread each")] = 1
    out: Annotated[str, arg("folder of clients.md, clients.json and the runs' results")] = (
        "research/results"
    )
    only_report: Annotated[bool, arg("rewrite the page from the runs' results")] = False


def jobs(args: Args) -> list[tuple[str, str, int, int]]:
    """Returns the (setting, client, seed, steps) of every run, residual ids first (short)."""
    out = []
    for setting in sorted(args.settings, key=lambda e: "Residual" not in e):
        steps = args.residual_steps if "Residual" in setting else args.steps
        out += [(setting, c, s, steps) for s in args.seeds for c in args.clients]
    return out


def main(argv: list[str] | None = None) -> None:
    args = parse(Args, argv, __doc__)
    one_or_more("--seeds", args.seeds, "one or more seeds")
    for c in args.clients:
        if c not in CLIENTS:
            raise ValueError(f"--clients {c!r} is invalid; allowed: {list(CLIENTS)}")
    for name in args.settings:
        if name not in SETTINGS:
            raise ValueError(f"--settings {name!r} is invalid; allowed: {list(SETTINGS)}")
    out = Path(args.out)
    todo = [j for j in jobs(args) if not run_path(out, *j).exists()]
    if not args.only_report and todo:
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(args.workers, mp_context=ctx) as pool:
            futures = [pool.submit(train_one, *j, args.eval_every, args.eval_seeds, out)
                       for j in todo]  # fmt: skip
            for f in futures:
                r = f.result()
                print(f"{r['setting']} {r['client']} seed {r['seed']}: "
                      f"{joints(r['final']['rms_deg'], 4)} deg (PD "
                      f"{joints(r['pd']['rms_deg'], 4)})", flush=True)  # fmt: skip
    runs = [json.loads(p.read_text()) for p in sorted((out / "clients_runs").glob("*/*/*.json"))]
    result = {"clients": CLIENTS, "settings": {k: list(v) for k, v in SETTINGS.items()},
              "zoo_entry": zoo_reacher(), "runs": runs, "eval_seeds": args.eval_seeds}  # fmt: skip
    save_json(out, "clients", result)
    (out / "clients.md").write_text(report(result))


def report(result: dict[str, Any]) -> str:
    """Returns the study's page: one row per (id, client), its seeds' final RMS against PD."""
    from tendon2r_gym.evaluation.metrics import smoothness_x_pd

    lines = [
        "# Ordinary PPO clients on the registered ids",
        "",
        "Produced by `python -m research.studies.clients` (research/studies/clients.py): each "
        "client trains on `gym.make(env_id)` with the id's defaults and nothing else changed, "
        "and is evaluated deterministically on the eval seeds "
        f"{result['eval_seeds']}, beside PD on the same episodes.  The ids start each episode "
        "off the reference (reset_noise_scale 0.02 rad), so the whole episode's RMS holds the "
        "transient that closes it; the settled RMS leaves the first 20 ms out "
        "(settled_rms_deg of tendon2r_gym.evaluation.metrics.tracking_metrics).",
        "",
        "| setting | client | seeds | steps | final RMS A / B (deg) per seed | "
        "settled RMS A / B (deg) per seed | PD RMS A / B, settled (deg) | beats PD | "
        "first beat PD at (steps) | tension rate x PD |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in result["runs"]:
        groups.setdefault((r["setting"], r["client"], r["steps"]), []).append(r)
    for (setting, client, _), runs in groups.items():
        runs.sort(key=lambda r: r["seed"])
        finals = "; ".join(joints(r["final"]["rms_deg"], 4) for r in runs)
        pd = runs[0]["pd"]
        wins = sum(r["final"]["beats_pd"] for r in runs)
        firsts = ", ".join(str(r["first_beats_pd_steps"] or "-") for r in runs)
        rate = ", ".join(f"{smoothness_x_pd(r['final'], pd)[1]:.1f}" for r in runs)
        seeds = ", ".join(str(r["seed"]) for r in runs)
        settled = "; ".join(joints(r["final"]["settled_rms_deg"], 4) for r in runs)
        pd_cell = f"{joints(pd['rms_deg'], 4)}, {joints(pd['settled_rms_deg'], 4)}"
        cells = [setting, client, seeds, runs[0]["steps"], finals, settled, pd_cell,
                 f"{wins} of {len(runs)}", firsts, rate]  # fmt: skip
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    lines += ["", "Clients:", ""] + [f"- `{k}`: {v}." for k, v in result["clients"].items()]
    lines += ["", "Settings (registered id, env kwargs over its defaults):", ""]
    lines += [f"- {k}: `{v[0]}` {v[1] or ''}" for k, v in result["settings"].items()]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
