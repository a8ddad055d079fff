"""Reading the model-side files of a run or bundle: the SB3 model zip, its VecNormalize
statistics and a bundle's bundle.json.  Whatever is wrong with one of them (truncated, not that
kind of file, missing a key, made for another observation size) is one ValueError that names
the file, says what is wrong and how to recover (`corrupt`, `mismatch`).

No file is unpickled unless asked (`TRUST_HELP`): a model file from someone else cannot
run code when it is loaded.

- The model zip: its policy is built from the zip's plain JSON (``data``: the policy class
  named in it, one of `POLICY_CLASSES`, its policy_kwargs and spaces) and its weights
  (``policy.pth``, read with ``torch.load(weights_only=True)``); the cloudpickled entries of
  ``data`` (schedules, spaces, the class itself) are never unpickled (`load_policy`,
  and `load_ppo` for training on from a model).
- The statistics: ``<name>_vecnormalize.npz``, plain arrays read with ``allow_pickle=False``
  (`NormStats`).  The ``<name>_vecnormalize.pkl`` of earlier versions (a pickle) is
  read only with ``trust_pickle=True`` or inside `trusting_pickle` (the commands'
  ``--trust-pickle``); otherwise it is a `PickleRefused` naming the file and the option.
"""

from __future__ import annotations

import base64
import contextlib
import contextvars
import dataclasses
import importlib
import io
import json
import pickle
import pickletools
import struct
import zipfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from tendon2r_gym.llvm import load_triton

#: How to get a good model file back.
RECOVER_MODEL = (
    "re-bundle it with tendon2r-bundle --replace from its run folder (a bundled model), resume "
    "its run from the last good checkpoint with tendon2r-train --resume, or re-train it"
)
#: SB3's first entry of a model zip: a file that starts with it and has lost it is truncated.
_MODEL_DATA = "data"
#: The entry of a model zip that holds the policy's weights (a state dict of tensors).
_POLICY_WEIGHTS = "policy.pth"


def corrupt(path: str | Path, what: str, recover: str = RECOVER_MODEL) -> ValueError:
    """Returns the project's error for a corrupt file (a model file, a bundle's record, a run
    record): ``<path> is <what>; to recover: <recover>``, on one line."""
    return ValueError(" ".join(f"{path} is {what}; to recover: {recover}".split()))


def mismatch(path: str | Path, what: str, theirs: Any, ours: Any, env: str) -> ValueError:
    """Returns the error for a readable model file made for another env: ``what`` (e.g.
    observation shape) is ``theirs`` in the file, ``ours`` in ``env``."""
    return ValueError(
        f"{path} does not match {env}: {what} {theirs} in the file, {ours} in the env; "
        f"to recover: {RECOVER_MODEL}"
    )


# -- the trust option --------------------------------------------------------------------------
#: The option that lets a loader unpickle, as the commands and the Python API name it.
TRUST_OPTION = "--trust-pickle (trust_pickle=True)"
#: Its help: what it does and when to use it.
TRUST_HELP = "load model files that may run code (pickle): only for files you made"
_TRUST: contextvars.ContextVar[bool] = contextvars.ContextVar("trust_pickle", default=False)


class PickleRefused(ValueError):
    """A file that only a pickle could read, refused because the trust option is off."""


@contextlib.contextmanager
def trusting_pickle(trust: bool = True) -> Iterator[None]:
    """Inside it, the loaders that are not given ``trust_pickle`` unpickle if ``trust`` (the
    commands' ``--trust-pickle``: `TRUST_HELP`)."""
    token = _TRUST.set(bool(trust))
    try:
        yield
    finally:
        _TRUST.reset(token)


def trusted(trust_pickle: bool | None = None) -> bool:
    """Returns whether a loader may unpickle: ``trust_pickle`` if given, else whether it runs
    inside `trusting_pickle`."""
    return _TRUST.get() if trust_pickle is None else bool(trust_pickle)


#: How to recover from a refused pickle of the statistics.
CONVERT = "convert it to plain files once (scripts/convert_model_files.py, or files.convert_stats)"


def refuse_pickle(path: str | Path, what: str, recover: str = CONVERT) -> PickleRefused:
    """Returns the error of a pickle read without the trust option: it names the file, what it
    is, how to do without it (``recover``) and the option."""
    return PickleRefused(
        f"{path} is {what}, which can run code when loaded; to recover: {recover}, or pass "
        f"{TRUST_OPTION} to {TRUST_HELP}"
    )


# -- model zip ---------------------------------------------------------------------------------
#: The policy classes a model zip may name, by the module and name SB3 recorded (MlpPolicy is
#: SB3's ActorCriticPolicy; SplitViewPolicy is a trained model's class, which the shipped
#: generalist_real model recorded under tendon2r_gym.policies.split_view).  The class is
#: imported from here, by name when a model is loaded, never unpickled.
POLICY_CLASSES = {
    ("stable_baselines3.common.policies", "ActorCriticPolicy"): (
        "stable_baselines3.common.policies",
        "ActorCriticPolicy",
    ),
    ("tendon2r_gym.policies.split_view", "SplitViewPolicy"): (
        "tendon2r_gym.training.split_view",
        "SplitViewPolicy",
    ),
    ("tendon2r_gym.training.split_view", "SplitViewPolicy"): (
        "tendon2r_gym.training.split_view",
        "SplitViewPolicy",
    ),
}
#: The space a model zip's observation and action spaces must be (as SB3 records its type).
_BOX = "<class 'gymnasium.spaces.box.Box'>"


def model_data(path: str | Path) -> dict[str, Any]:
    """Returns the plain JSON ``data`` of an SB3 model zip (its spaces and settings; the
    cloudpickled entries stay unread base64 text) after checking that its weights read as
    tensors alone (``torch.load(weights_only=True)``)."""
    data, _ = _read_zip(Path(path))
    return data


def _read_zip(path: Path) -> tuple[dict[str, Any], dict[str, Any]]:
    """Returns (plain ``data``, policy state dict) of a model zip; a file that is not a whole
    one, or whose weights are not tensors alone, is a ValueError naming it."""
    load_triton()  # before torch: tendon2r_gym.llvm
    import torch

    _exists(path)
    try:
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
            raw = {n: z.read(n) for n in (_MODEL_DATA, _POLICY_WEIGHTS) if n in names}
    except Exception as e:  # noqa: BLE001 (anything unreadable is a corrupt file)
        raise corrupt(path, f"{_zip_state(path)} ({type(e).__name__}: {e})") from None
    if len(raw) < 2:
        raise corrupt(path, _zip_state(path))
    try:
        data = json.loads(raw[_MODEL_DATA])
    except ValueError as e:  # not UTF-8, or not JSON
        raise corrupt(path, f"not an SB3 model zip (its data entry is not JSON: {e})") from None
    try:
        weights = torch.load(
            io.BytesIO(raw[_POLICY_WEIGHTS]), map_location="cpu", weights_only=True
        )
    except Exception as e:  # noqa: BLE001 (anything but plain tensors is refused)
        raise corrupt(
            path, f"not an SB3 model zip of plain weights ({_POLICY_WEIGHTS}: {_refusal(e)})"
        ) from None
    if not isinstance(data, dict) or not isinstance(weights, dict) or not weights:
        raise corrupt(path, "not an SB3 model zip (no data object, or no weights in policy.pth)")
    return data, weights


def _refusal(error: Exception) -> str:
    """Returns why ``torch.load(weights_only=True)`` refused a file, on one line (without
    torch's advice to load it with weights_only=False)."""
    text = " ".join(str(error).split())
    _, found, reason = text.partition("WeightsUnpickler error:")
    reason = reason.split(" Check the documentation")[0].strip() if found else text[:200]
    return f"{type(error).__name__}: {reason} (it does not load as tensors alone)"


def check_model_spaces(
    path: str | Path,
    data: dict[str, Any],
    obs_shape: tuple[int, ...],
    action_shape: tuple[int, ...],
    env: str,
) -> None:
    """Raises if the model zip's observation or action space (``data``: `model_data`)
    differs in shape from what ``env`` gives it."""
    for what, key, ours in (
        ("observation shape", "observation_space", tuple(obs_shape)),
        ("action shape", "action_space", tuple(action_shape)),
    ):
        theirs = _space_shape(path, data, key)
        if theirs != ours:
            raise mismatch(path, what, theirs, ours, env)


def _space_shape(path: str | Path, data: dict[str, Any], key: str) -> tuple[int, ...]:
    """Returns the shape of a Box space of ``data`` (its plain ``_shape``)."""
    space = data.get(key)
    if not isinstance(space, dict) or space.get(":type:") != _BOX:
        raise corrupt(path, f"not a model zip of this env's kind ({key}: not a Box)")
    shape = space.get("_shape")
    if not isinstance(shape, list) or not all(type(n) is int and n >= 0 for n in shape):
        raise corrupt(path, f"not a model zip of this env's kind ({key}: shape {shape!r})")
    return tuple(shape)


def _box(path: Path, data: dict[str, Any], key: str) -> Any:
    """Returns the Box space ``key`` of ``data`` from its plain fields (shape, dtype, and the
    bounds as numpy printed them), without unpickling it."""
    from gymnasium import spaces

    shape = _space_shape(path, data, key)
    space = data[key]
    dtype = space.get("dtype")
    if dtype not in ("float32", "float64"):
        raise corrupt(path, f"not a model zip of this env's kind ({key}: dtype {dtype!r})")
    bounds = [_printed_array(space.get(side), shape) for side in ("low", "high")]
    if any(b is None for b in bounds):
        raise corrupt(path, f"not a model zip this loader reads ({key}: unreadable bounds)")
    low, high = (bound.astype(dtype) for bound in bounds)  # as numpy printed them: exact
    return spaces.Box(low, high, shape, dtype=np.dtype(dtype))


def _printed_array(text: Any, shape: tuple[int, ...]) -> np.ndarray | None:
    """Returns the array of ``shape`` that numpy printed as ``text`` ('[-1. -1.]'), or None if
    it is not all there (numpy summarizes a long array with '...')."""
    if not isinstance(text, str) or "..." in text:
        return None
    try:
        values = [float(t) for t in text.replace("[", " ").replace("]", " ").split()]
    except ValueError:
        return None
    return np.array(values).reshape(shape) if len(values) == int(np.prod(shape)) else None


def _pickled_global(entry: Any) -> tuple[str, str] | None:
    """Returns (module, name) of a class that SB3 recorded by reference (a pickle that only
    names it), read from the pickle's opcodes without running it; None for anything else."""
    if not isinstance(entry, dict) or not isinstance(entry.get(":serialized:"), str):
        return None
    try:
        ops = list(pickletools.genops(base64.b64decode(entry[":serialized:"], validate=True)))
    except Exception:  # noqa: BLE001 (not a pickle that parses: not a class by reference)
        return None
    strings = {"SHORT_BINUNICODE", "BINUNICODE", "UNICODE", "BINUNICODE8"}
    plain = [(op.name, arg) for op, arg, _ in ops if op.name not in ("PROTO", "FRAME", "MEMOIZE")]
    kinds = [name for name, _ in plain]
    if len(plain) == 4 and kinds[0] in strings and kinds[1] in strings:
        if kinds[2:] == ["STACK_GLOBAL", "STOP"]:
            return str(plain[0][1]), str(plain[1][1])
    if kinds == ["GLOBAL", "STOP"]:
        module, _, name = str(plain[0][1]).partition(" ")
        return module, name
    return None


def _policy_class(path: Path, data: dict[str, Any]) -> Any:
    """Returns the policy class a model zip names, if it is one of `POLICY_CLASSES`."""
    named = _pickled_global(data.get("policy_class"))
    if named not in POLICY_CLASSES:
        shown = ".".join(named) if named else "a class that is not named by reference"
        allowed = ", ".join(sorted({".".join(v) for v in POLICY_CLASSES.values()}))
        raise ValueError(
            f"{path} records the policy class {shown}; allowed: {allowed} (the classes "
            f"built without unpickling); to recover: {RECOVER_MODEL}"
        )
    module, name = POLICY_CLASSES[named]
    return getattr(importlib.import_module(module), name)


def _policy_kwargs(path: Path, data: dict[str, Any]) -> dict[str, Any]:
    """Returns the plain policy_kwargs of a model zip, as SB3's load reads them (no device; an
    old ``[dict(pi=..., vf=...)]`` net_arch as its dict)."""
    kwargs = data.get("policy_kwargs", {})
    if not isinstance(kwargs, dict) or ":serialized:" in kwargs:
        raise ValueError(
            f"{path} records policy_kwargs that only a pickle holds; allowed: plain JSON "
            f"policy_kwargs (net_arch, log_std_init, ...); to recover: {RECOVER_MODEL}"
        )
    kwargs = {k: v for k, v in kwargs.items() if k != "device"}
    arch = kwargs.get("net_arch")
    if isinstance(arch, list) and arch and isinstance(arch[0], dict):
        kwargs["net_arch"] = arch[0]
    return kwargs


class SavedModel:
    """A model zip's policy (SB3's ActorCriticPolicy as `load_policy` built it) behind
    the ``predict`` of SB3's PPO."""

    def __init__(self, policy: Any, path: Path) -> None:
        self.policy = policy
        self.path = path

    @property
    def observation_space(self) -> Any:
        return self.policy.observation_space

    @property
    def action_space(self) -> Any:
        return self.policy.action_space

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, Any]:
        """SB3's ``PPO.predict``: the policy's action for ``observation``."""
        return self.policy.predict(observation, state, episode_start, deterministic)


def load_policy(path: str | Path) -> SavedModel:
    """Returns the policy of an SB3 model zip, built without unpickling (module docstring):
    the class the zip names (`POLICY_CLASSES`), its plain policy_kwargs and spaces, and
    its weights; a zip that does not build or whose weights do not fit is a ValueError
    naming it.  Loading it leaves torch's random state as it was."""
    load_triton()  # before torch: tendon2r_gym.llvm
    import torch

    path = Path(path)
    data, weights = _read_zip(path)
    cls = _policy_class(path, data)
    kwargs = _policy_kwargs(path, data)
    spaces = _box(path, data, "observation_space"), _box(path, data, "action_space")
    try:
        with torch.random.fork_rng(devices=[]):  # its initial weights are replaced below
            policy = cls(*spaces, _no_schedule, use_sde=bool(data.get("use_sde")), **kwargs)
        policy.load_state_dict(weights, strict=True)
    except Exception as e:  # noqa: BLE001 (a policy that does not build is one error)
        raise ValueError(
            f"{path} does not load ({type(e).__name__}: {e}); to recover: {RECOVER_MODEL}"
        ) from None
    policy.set_training_mode(False)
    return SavedModel(policy, path)


def _no_schedule(_: float) -> float:
    """The learning rate of a policy that only acts (its optimizer never steps)."""
    return 0.0


def load_ppo(
    path: str | Path,
    env: Any,
    ppo_kwargs: dict[str, Any],
    seed: int | None = None,
    tensorboard_log: str | None = None,
) -> Any:
    """Returns SB3's PPO on ``env`` with the weights, optimizer state and step counters of a
    model zip, built without unpickling: as SB3's ``PPO.load`` would, but with the policy
    class and policy_kwargs from the zip's plain JSON (`load_policy`), the PPO settings
    ``ppo_kwargs`` (the run's, as config.yaml records them) and the zip's seed unless
    ``seed``; the weights and optimizer state through SB3's ``set_parameters`` (which reads
    them with ``weights_only=True``)."""
    load_triton()  # before torch: tendon2r_gym.llvm
    from stable_baselines3 import PPO

    path = Path(path)
    data, _ = _read_zip(path)
    obs_shape, action_shape = env.observation_space.shape, env.action_space.shape
    check_model_spaces(path, data, obs_shape, action_shape, "the run's training env")
    cls, policy_kwargs = _policy_class(path, data), _policy_kwargs(path, data)
    recorded_seed = data.get("seed") if type(data.get("seed")) is int else None
    kwargs = {"use_sde": bool(data.get("use_sde")), **ppo_kwargs}
    try:
        model = PPO(
            cls, env, policy_kwargs=policy_kwargs, seed=recorded_seed if seed is None else seed,
            device="cpu", verbose=0, tensorboard_log=tensorboard_log, **kwargs,
        )  # fmt: skip
        model.set_parameters(str(path), exact_match=True, device="cpu")
    except Exception as e:  # noqa: BLE001 (a model that does not load is one error)
        raise ValueError(
            f"{path} does not load ({type(e).__name__}: {e}); to recover: {RECOVER_MODEL}"
        ) from None
    for key in ("num_timesteps", "_n_updates", "_episode_num"):
        if type(data.get(key)) is int:
            setattr(model, key, data[key])
    return model


def load_model(
    path: str | Path, cls: Any = None, trust_pickle: bool | None = None, **kwargs: Any
) -> Any:
    """Returns ``cls.load(path, **kwargs)`` (default: SB3's PPO), which unpickles the zip's
    ``data``: only with the trust option (`trusted`), else a `PickleRefused`
    (`load_policy` reads the policy without it).  A file SB3 cannot read is a ValueError
    naming it."""
    path = Path(path)
    _exists(path)
    if not trusted(trust_pickle):
        no_pickle = "read its policy with load_policy, or train on from it with load_ppo"
        raise refuse_pickle(path, "read by SB3's load through pickle", no_pickle)
    if cls is None:
        load_triton()  # before torch: tendon2r_gym.llvm
        from stable_baselines3 import PPO

        cls = PPO
    try:
        return cls.load(path, **kwargs)
    except Exception as e:  # noqa: BLE001 (anything SB3 cannot load is one error naming it)
        model_data(path)  # raises if the file itself is unreadable
        raise ValueError(
            f"{path} does not load ({type(e).__name__}: {e}); to recover: {RECOVER_MODEL}"
        ) from None


def _zip_state(path: Path) -> str:
    """Returns what is wrong with a zip SB3 found no model in: truncated (it starts as an SB3
    model zip does, with its ``data`` entry), or not a model zip at all."""
    with path.open("rb") as f:
        head = f.read(30 + len(_MODEL_DATA))  # a zip's first local header and name
    if len(head) >= 30 and head[:4] == b"PK\x03\x04":
        size = struct.unpack("<H", head[26:28])[0]
        if head[30 : 30 + size] == _MODEL_DATA.encode():
            return "truncated (an SB3 model zip whose end is missing or damaged)"
    return "not an SB3 model zip (no readable 'data' entry and weights)"


# -- VecNormalize statistics -------------------------------------------------------------------
#: The version of the statistics file's layout (its ``format`` array).
STATS_FORMAT = 1
#: The statistics file's arrays: name -> (shape: "vector", or "scalar"; kind).
STATS_ARRAYS = {
    "format": ("scalar", "int"),
    "obs_mean": ("vector", "float"),
    "obs_var": ("vector", "float"),
    "obs_count": ("scalar", "float"),
    "ret_mean": ("scalar", "float"),
    "ret_var": ("scalar", "float"),
    "ret_count": ("scalar", "float"),
    "norm_obs": ("scalar", "bool"),
    "norm_reward": ("scalar", "bool"),
    "training": ("scalar", "bool"),
    "clip_obs": ("scalar", "float"),
    "clip_reward": ("scalar", "float"),
    "gamma": ("scalar", "float"),
    "epsilon": ("scalar", "float"),
}
_KINDS = {"int": "i", "float": "f", "bool": "b"}


@dataclasses.dataclass(frozen=True, eq=False)  # arrays: compare them with arrays()
class NormStats:
    """SB3's VecNormalize statistics as plain values: the observations' running mean,
    variance and count, the returns' (for reward normalization), and its settings.  Saved as
    numpy's npz of `STATS_ARRAYS` and read with ``allow_pickle=False``."""

    obs_mean: np.ndarray
    obs_var: np.ndarray
    obs_count: float
    ret_mean: float
    ret_var: float
    ret_count: float
    norm_obs: bool
    norm_reward: bool
    training: bool
    clip_obs: float
    clip_reward: float
    gamma: float
    epsilon: float

    @property
    def obs_shape(self) -> tuple[int, ...]:
        return tuple(self.obs_mean.shape)

    @classmethod
    def of(cls, vecnorm: Any, path: str | Path = "VecNormalize") -> NormStats:
        """Returns the statistics of an SB3 VecNormalize (of a Box observation)."""
        obs, ret = vecnorm.obs_rms, vecnorm.ret_rms
        if isinstance(obs, dict):
            raise ValueError(f"{path}: dict observations are not supported; allowed: a Box")
        return cls(
            np.array(obs.mean, dtype=np.float64), np.array(obs.var, dtype=np.float64),
            float(obs.count), float(ret.mean), float(ret.var), float(ret.count),
            bool(vecnorm.norm_obs), bool(vecnorm.norm_reward), bool(vecnorm.training),
            float(vecnorm.clip_obs), float(vecnorm.clip_reward), float(vecnorm.gamma),
            float(vecnorm.epsilon),
        )  # fmt: skip

    def arrays(self) -> dict[str, np.ndarray]:
        """Returns the arrays of its file (`STATS_ARRAYS`)."""
        values = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        return {"format": np.array(STATS_FORMAT), **{k: np.array(v) for k, v in values.items()}}

    def save(self, path: str | Path) -> None:
        """Writes its npz to ``path`` (the name as given: numpy adds no suffix)."""
        with open(path, "wb") as f:
            np.savez(f, **self.arrays())

    def vecnormalize(self, venv: Any) -> Any:
        """Returns SB3's VecNormalize wrapping ``venv`` with these statistics and settings:
        its observations normalized as by the VecNormalize they were saved from."""
        load_triton()  # before torch: tendon2r_gym.llvm
        from stable_baselines3.common.vec_env import VecNormalize

        out = VecNormalize(
            venv, training=self.training, norm_obs=self.norm_obs, norm_reward=self.norm_reward,
            clip_obs=self.clip_obs, clip_reward=self.clip_reward, gamma=self.gamma,
            epsilon=self.epsilon,
        )  # fmt: skip
        out.obs_rms.mean, out.obs_rms.var = self.obs_mean.copy(), self.obs_var.copy()
        out.obs_rms.count = self.obs_count
        out.ret_rms.mean, out.ret_rms.var = np.float64(self.ret_mean), np.float64(self.ret_var)
        out.ret_rms.count = self.ret_count
        return out


def read_stats(path: str | Path, trust_pickle: bool | None = None) -> NormStats:
    """Returns the statistics of a ``.npz`` file (read with ``allow_pickle=False``), or of an
    earlier version's ``.pkl`` only with the trust option (`trusted`; else a
    `PickleRefused`).  A file that is not whole is a ValueError naming it."""
    path = Path(path)
    _exists(path)
    if path.suffix == ".pkl":
        if not trusted(trust_pickle):
            raise refuse_pickle(
                path, "a pickle (the VecNormalize statistics of an earlier version)"
            )
        return NormStats.of(_unpickled_vecnormalize(path), path)
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except Exception as e:  # noqa: BLE001 (anything numpy cannot read is a corrupt file)
        raise corrupt(path, f"{_npz_state(path)} ({type(e).__name__}: {e})") from None
    return _stats_of(path, arrays)


def _npz_state(path: Path) -> str:
    """Returns what is wrong with a statistics file numpy cannot read: truncated (empty, or a
    zip whose end is missing), or not an npz at all."""
    with path.open("rb") as f:
        head = f.read(4)
    if not head or head == b"PK\x03\x04":
        return "truncated (a statistics npz whose end is missing or damaged)"
    return "not a statistics npz (numpy's zip of plain arrays)"


def _stats_of(path: Path, arrays: dict[str, np.ndarray]) -> NormStats:
    """Returns the statistics of a file's ``arrays`` after checking each (`STATS_ARRAYS`)."""
    for name, (shape, kind) in STATS_ARRAYS.items():
        if name not in arrays:
            raise corrupt(path, f"not a statistics npz of this version (no array {name!r})")
        a = arrays[name]
        ndim = 1 if shape == "vector" else 0
        if a.ndim != ndim or a.dtype.kind not in _KINDS[kind]:
            raise corrupt(path, f"invalid: {name} is a {a.dtype} array of shape {a.shape}")
    if int(arrays["format"]) != STATS_FORMAT:
        raise corrupt(path, f"of another format ({int(arrays['format'])}, not {STATS_FORMAT})")
    mean, var = arrays["obs_mean"].astype(np.float64), arrays["obs_var"].astype(np.float64)
    if mean.shape != var.shape or not (np.all(np.isfinite(mean)) and np.all(var >= 0)):
        raise corrupt(path, "invalid: obs_mean and obs_var are not a mean and a variance")
    plain = {k: arrays[k].item() for k, (shape, _) in STATS_ARRAYS.items() if shape == "scalar"}
    plain.pop("format")
    return NormStats(mean, var, **plain)


def _unpickled_vecnormalize(path: Path) -> Any:
    """Returns the VecNormalize an earlier version's pkl holds (the first half of SB3's
    VecNormalize.load): only called with the trust option."""
    load_triton()  # before torch: tendon2r_gym.llvm
    from stable_baselines3.common.vec_env import VecNormalize

    try:
        with path.open("rb") as f:
            stats = pickle.load(f)  # noqa: S301 (the trust option is on: read_stats)
    except Exception as e:  # noqa: BLE001 (anything pickle cannot read is a corrupt file)
        what = "truncated" if isinstance(e, EOFError) or "truncated" in str(e) else "unreadable"
        raise corrupt(path, f"{what} (not a whole VecNormalize pickle: {e})") from None
    if not isinstance(stats, VecNormalize):
        raise corrupt(path, f"not a VecNormalize pickle (it holds a {type(stats).__name__})")
    return stats


def load_vecnormalize(
    path: str | Path, venv: Any, env: str = "the env", trust_pickle: bool | None = None
) -> Any:
    """Returns SB3's VecNormalize of a statistics file (`read_stats`) wrapping ``venv``,
    after checking that it normalizes observations of venv's shape."""
    stats = read_stats(path, trust_pickle)
    check_stats_shape(path, stats, venv.observation_space.shape, env)
    return stats.vecnormalize(venv)


def check_stats_shape(
    path: str | Path, stats: NormStats, obs_shape: tuple[int, ...], env: str
) -> None:
    """Raises if the statistics ``stats`` normalize observations of another shape."""
    if stats.obs_shape != tuple(obs_shape):
        raise mismatch(path, "observation shape", stats.obs_shape, tuple(obs_shape), env)


def convert_stats(pkl: str | Path, npz: str | Path, trust_pickle: bool | None = None) -> NormStats:
    """Writes the statistics of an earlier version's pkl as the npz ``npz`` (unpickling it:
    only with the trust option) and returns them."""
    stats = read_stats(Path(pkl), trust_pickle)
    stats.save(npz)
    return stats


# -- JSON records ------------------------------------------------------------------------------
def read_json(path: str | Path, keys: Iterable[str], recover: str) -> dict[str, Any]:
    """Returns the JSON object in ``path`` after checking that it has every key of ``keys``."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except UnicodeDecodeError as e:
        raise corrupt(path, f"not JSON text ({e})", recover) from None
    except json.JSONDecodeError as e:
        raise corrupt(path, f"not JSON ({e})", recover) from None
    if not isinstance(data, dict):
        raise corrupt(path, f"not a JSON object (it holds a {type(data).__name__})", recover)
    missing = [k for k in keys if k not in data]
    if missing:
        raise corrupt(path, f"missing key {missing[0]!r}", recover)
    return data


def _exists(path: Path) -> None:
    if not path.is_file():
        raise corrupt(path, "missing")
