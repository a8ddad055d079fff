"""The diagnosis probes behind Tendon2R-v2: one client, one seed, one factor changed.

    python research/studies/client_probes.py Tendon2R-v1 '{"action_filter_tau": 0.002}' sb3 300000 0 \
        >> research/results/client_probes.jsonl
    python -c "from research.studies.client_probes import report; report()"   # the page

Each probe trains SB3 PPO on ``gym.make(env_id, **kwargs)`` for ``steps`` steps and prints one
JSON line: the final model's RMS error per joint (deterministic, eval seeds 10000-10002) and
its RMS tension rate, beside PD's on the same episodes.  Clients: ``sb3`` (SB3's defaults in
VecNormalize), ``sb3_raw`` (no normalization), ``zoo`` (rl_zoo3's Reacher-v2 entry with its
VecNormalize), ``cleanrl`` (SB3's defaults, learning rate annealed).  Two env changes are
tried here as wrappers rather than env options: ``_ff`` (the action centred on the tension
that holds the reference, computed torque with zero gains, at that fraction of the force
limit) and ``_rate`` ([weight, horizon]: a log kernel of the error rate times horizon).  The
study that reports the ids is research/studies/clients.py.
"""  # noqa: E501
import json
import sys
import time
from typing import Any

import numpy as np

from tendon2r_gym.formatting import pair

#: rl_zoo3's shipped Reacher-v2 entry (research/studies/clients.py reads it from rl_zoo3).
ZOO = dict(batch_size=32, n_steps=512, gamma=0.9, learning_rate=0.000104019,
           ent_coef=7.52585e-08, clip_range=0.3, n_epochs=5, gae_lambda=1.0,
           max_grad_norm=0.9, vf_coef=0.950368)  # fmt: skip
EVAL_SEEDS = (10000, 10001, 10002)


def probe(argv: list[str]) -> dict[str, Any]:
    """Runs one probe: argv is (env_id, kwargs as JSON, client, steps, seed)."""
    import gymnasium as gym
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    import tendon2r_gym  # noqa: F401  (registers the ids)
    from tendon2r_gym.policies.baselines import ComputedTorquePolicy, PDPolicy
    from tendon2r_gym.task.observation import DQ, DQ_DES, Q_DES, Q

    torch.set_num_threads(1)
    env_id, kwargs, client = argv[0], json.loads(argv[1]), argv[2]
    steps, seed = int(argv[3]), int(argv[4])
    given = dict(kwargs)
    ff, rate = kwargs.pop("_ff", None), kwargs.pop("_rate", None)

    class FeedForward(gym.Wrapper):
        """The action centred on computed torque's command with zero gains, scaled by ff."""

        def __init__(self, env: gym.Env) -> None:
            super().__init__(env)
            self.ct = ComputedTorquePolicy.from_env(env)
            self.ct.kp, self.ct.kd = self.ct.kp * 0, self.ct.kd * 0

        def reset(self, **kw: Any):
            self._obs, info = self.env.reset(**kw)
            self.ct.reset(info)
            return self._obs, info

        def step(self, a: np.ndarray):
            at_reference = self._obs.copy()
            at_reference[Q], at_reference[DQ] = at_reference[Q_DES], at_reference[DQ_DES]
            u = self.ct.predict(at_reference)[0] + ff * np.clip(a, -1, 1)
            self._obs, *rest = self.env.step(np.clip(u, -1, 1).astype(np.float32))
            return (self._obs, *rest)

    class RateReward(gym.Wrapper):
        """Subtracts rate[0] times a log kernel of the error rate times rate[1] (deg)."""

        def step(self, a: np.ndarray):
            obs, r, te, tr, info = self.env.step(a)
            de = (obs[DQ_DES] - obs[DQ]) * 180 / np.pi * rate[1]
            r = r - rate[0] * float(np.mean(np.log1p(de**2)) / (2 * np.log1p(180**2)))
            return obs, r, te, tr, info

    def make(raw: bool = False) -> gym.Env:
        env = gym.make(env_id, **kwargs)
        if ff is not None:
            env = FeedForward(env)
        if rate is not None and not raw:
            env = RateReward(env)
        return env

    venv: Any = DummyVecEnv([make])
    if client in ("sb3", "zoo", "cleanrl"):
        venv = VecNormalize(venv, gamma=ZOO["gamma"] if client == "zoo" else 0.99)
    hp: dict[str, Any] = {}
    if client == "zoo":
        hp = ZOO
    if client == "cleanrl":
        hp = dict(learning_rate=lambda f: 3e-4 * f, max_grad_norm=0.5)
    model = PPO("MlpPolicy", venv, seed=seed, verbose=0, **hp)
    start = time.time()
    model.learn(steps)
    wall = time.time() - start

    def run(policy: Any, s: int) -> tuple[np.ndarray, np.ndarray]:
        env = make() if policy == "ppo" else gym.make(env_id, **kwargs)
        obs, info = env.reset(seed=s)
        if hasattr(policy, "reset"):
            policy.reset(info)
        errs, tens, done = [], [], False
        while not done:
            if policy == "ppo":
                o = venv.normalize_obs(obs) if isinstance(venv, VecNormalize) else obs
                a, _ = model.predict(o, deterministic=True)
            else:
                a, _ = policy.predict(obs)
            obs, r, term, trunc, info = env.step(a)
            errs.append(info["tracking_error_deg"])
            tens.append(info["tendon_tension"])
            done = term or trunc
        return np.array(errs), np.array(tens)

    out: dict[str, Any] = {}
    ctrl_dt = gym.make(env_id, **kwargs).unwrapped.ctrl_dt
    for name in ("ppo", "pd"):
        pol = "ppo" if name == "ppo" else PDPolicy.from_env(gym.make(env_id, **kwargs))
        traces = [run(pol, s) for s in EVAL_SEEDS]
        e = np.concatenate([t[0] for t in traces])
        rate_ = np.concatenate([np.diff(t[1], axis=0) for t in traces]) / ctrl_dt
        out[name] = dict(rms=np.sqrt(np.mean(e**2, 0)).round(4).tolist(),
                         rate=np.sqrt(np.mean(rate_**2, 0)).round(2).tolist())  # fmt: skip
    return dict(env=env_id, kw=given, client=client, steps=steps, seed=seed, wall=round(wall),
                **out)  # fmt: skip


def report() -> None:
    """Writes research/results/client_probes.md from client_probes.jsonl."""
    from pathlib import Path

    here = Path(__file__).resolve().parents[1] / "results"
    rows = [json.loads(line) for line in (here / "client_probes.jsonl").read_text().splitlines()]
    lines = [
        "# Diagnosis probes: one client, one seed, one factor",
        "",
        "Produced by `research/studies/client_probes.py` (one line of client_probes.jsonl per "
        "probe): SB3 PPO for the given steps on the given id and kwargs, the final model "
        "evaluated deterministically on seeds 10000-10002, beside PD on the same episodes.",
        "",
        "| id | kwargs | client | steps | seed | RMS A / B (deg) | PD RMS A / B (deg) | "
        "tension rate (N/s) | PD's (N/s) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        ppo, pd = r["ppo"], r["pd"]
        cells = [r["env"], json.dumps(r["kw"]), r["client"], r["steps"], r["seed"],
                 pair(ppo["rms"]), pair(pd["rms"]), pair(ppo["rate"], ".1f"),
                 pair(pd["rate"], ".1f")]  # fmt: skip
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    (here / "client_probes.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    print(json.dumps(probe(sys.argv[1:])), flush=True)
