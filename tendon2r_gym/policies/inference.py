"""A trained actor's deterministic action, bit for bit the same on every machine.

SB3's ``predict`` runs the actor in float32 torch, whose matrix products and tanh go through
kernels chosen by the CPU's instruction set (AVX2, AVX-512) and thread count (MKL, oneDNN,
torch's own vectorized code): their summation order, and so the last bits of an action,
differ from one machine to another.  On an arm that the policy keeps unstable, the closed
loop amplifies those bits until whole benchmark figures differ.

`predict` evaluates the same actor in float64 with numpy's elementwise operations only
(multiply, add, divide: IEEE-754 correctly rounded whatever the CPU's instruction set) in an
order fixed here: each sum of a layer as a pairwise tree, tanh from `exp` of a fixed
polynomial; no BLAS, no libm, no threads.  It covers SB3's ActorCriticPolicy as SB3 builds
it (its MlpPolicy, and the masked input of tendon2r_gym.training.split_view.SplitViewPolicy):
a flattened Box observation, Linear layers with Tanh or ReLU, and a Box action whose
deterministic action is the mean, clipped to the action space.  It reads the weights again
whenever they change (training evaluates its live model).  Its actions equal SB3's to
float32 rounding (its input is rounded to float32, as SB3's is, and so is its action).
Another policy, or a stochastic action, runs through SB3's ``predict``.
"""

from __future__ import annotations

import math
import weakref
from typing import Any

import numpy as np

#: ln 2 in two parts (fdlibm): k * LN2_HI is exact for |k| < 2**20.
LN2_HI, LN2_LO = 6.93147180369123816490e-01, 1.90821492927058770002e-10
#: exp(r) on |r| <= ln(2) / 2 as its Taylor series to r**13 (next term < 5e-18).
EXP_TAYLOR = [1.0 / math.factorial(k) for k in range(14)]
#: Below this, exp(2 * -|x|) no longer changes tanh(x) = +-1 in float64.
TANH_SATURATES = 20.0


def exp(y: np.ndarray) -> np.ndarray:
    """Returns e**y for ``y`` in [-745, 709] to a few float64 ulps, the same bits on every
    IEEE-754 machine: y = k ln 2 + r, e**y = 2**k e**r, e**r by Horner."""
    y = np.asarray(y, dtype=np.float64)
    k = np.rint(y / LN2_HI)
    r = (y - k * LN2_HI) - k * LN2_LO
    p = np.full_like(r, EXP_TAYLOR[-1])
    for c in reversed(EXP_TAYLOR[:-1]):
        p = p * r + c
    return np.ldexp(p, k.astype(np.int64))


def tanh(x: np.ndarray) -> np.ndarray:
    """Returns tanh(x) to float64 rounding (absolute error < 1e-15), the same bits on every
    IEEE-754 machine: (1 - e) / (1 + e) with e = exp(-2|x|), signed as x."""
    e = exp(-2.0 * np.minimum(np.abs(x), TANH_SATURATES))
    return np.copysign((1.0 - e) / (1.0 + e), x)


def relu(x: np.ndarray) -> np.ndarray:
    """Returns max(x, 0)."""
    return np.maximum(x, 0.0)


#: Products held at once by `linear` (256 kB of float64: a chunk stays in cache).
CHUNK = 32768


def linear(x: np.ndarray, weight: np.ndarray, bias: np.ndarray | None) -> np.ndarray:
    """Returns x @ weight.T + bias (``x`` (n, in), ``weight`` (out, in)), each sum over ``in``
    as a pairwise tree of elementwise adds (a fixed order, no BLAS): padded with zeros to a
    power of two, the first half plus the second, until one is left; a chunk of outputs at a
    time (which does not change any sum's order)."""
    (n, n_in), n_out = x.shape, weight.shape[0]
    width = 1 << max(n_in - 1, 0).bit_length()  # the next power of two
    step = max(1, CHUNK // (width * n))
    out = np.empty((n, n_out))
    buffer = np.zeros((width, n, min(step, n_out)))  # (in, n, out): a block per input
    for lo in range(0, n_out, step):
        terms = buffer[:, :, : min(step, n_out - lo)]
        np.multiply(x.T[:, :, None], weight[lo : lo + step].T[:, None, :], out=terms[:n_in])
        half = width
        while half > 1:
            half //= 2
            np.add(terms[:half], terms[half : 2 * half], out=terms[:half])
        out[:, lo : lo + step] = terms[0]
    return out if bias is None else out + bias


#: SplitViewPolicy's features extractor, by its class's module and name (a model class: it
#: lives where models are trained, tendon2r_gym.training.split_view): its input times a mask.
MASKED_FLATTEN = ("tendon2r_gym.training.split_view", "MaskedFlatten")


def _as64(tensor: Any) -> np.ndarray:
    return tensor.detach().cpu().numpy().astype(np.float64)


def actor_layers(policy: Any) -> list[tuple[str, Any]] | None:
    """Returns the actor of an SB3 policy as a list of (kind, parameters): ``mask`` (the
    features extractor's 0/1 mask), ``linear`` ((weight, bias) as float64), ``tanh`` or
    ``relu``; None if the policy is not one `predict` covers (module docstring)."""
    from gymnasium import spaces
    from stable_baselines3.common.distributions import DiagGaussianDistribution
    from stable_baselines3.common.policies import ActorCriticPolicy
    from stable_baselines3.common.torch_layers import FlattenExtractor, MlpExtractor
    from torch import nn

    as_built = ("_predict", "get_distribution", "extract_features", "_get_action_dist_from_latent")
    if not (
        isinstance(policy, ActorCriticPolicy)
        and all(getattr(type(policy), f) is getattr(ActorCriticPolicy, f) for f in as_built)
        and type(policy.mlp_extractor) is MlpExtractor
        and isinstance(policy.observation_space, spaces.Box)
        and isinstance(policy.action_space, spaces.Box)
        and isinstance(policy.action_dist, DiagGaussianDistribution)
        and not policy.squash_output
    ):
        return None
    extractor = policy.pi_features_extractor
    if (type(extractor).__module__, type(extractor).__qualname__) == MASKED_FLATTEN:
        layers: list[tuple[str, Any]] = [("mask", _as64(extractor.keep))]
    elif type(extractor) is FlattenExtractor:
        layers = []
    else:
        return None
    kinds = {nn.Tanh: "tanh", nn.ReLU: "relu"}
    for module in [*policy.mlp_extractor.policy_net, policy.action_net]:
        if type(module) is nn.Linear:
            bias = None if module.bias is None else _as64(module.bias)
            layers.append(("linear", (_as64(module.weight), bias)))
        elif type(module) in kinds:
            layers.append((kinds[type(module)], None))
        else:
            return None
    return layers


#: Per policy, its actor_layers and the identities and versions of the tensors they were read
#: from: read again when training changes the weights (in place, which bumps a version).
_READ: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _actor(policy: Any) -> list[tuple[str, Any]] | None:
    """Returns `actor_layers` of ``policy``, read again only when its weights changed."""
    try:
        stamp = tuple((id(p), p._version) for p in policy.parameters())
    except (AttributeError, TypeError):  # not a torch module: nothing to cache
        return actor_layers(policy)
    read = _READ.get(policy)
    if read is None or read[0] != stamp:
        read = _READ[policy] = (stamp, actor_layers(policy))
    return read[1]


def actor_mean(layers: list[tuple[str, Any]], observation: np.ndarray) -> np.ndarray:
    """Returns the actor's mean action (n, n_actions) for a batch of normalized observations
    (n, ...), rounded to float32 first as SB3 feeds them to torch."""
    x = np.asarray(observation, dtype=np.float32).astype(np.float64)
    x = x.reshape(x.shape[0], -1)
    for kind, params in layers:
        if kind == "mask":
            x = x * params
        elif kind == "linear":
            x = linear(x, *params)
        else:
            x = tanh(x) if kind == "tanh" else relu(x)
    return x


def predict(
    model: Any,
    observation: np.ndarray,
    state: Any = None,
    episode_start: Any = None,
    deterministic: bool = True,
) -> tuple[np.ndarray, Any]:
    """Returns SB3's ``model.predict(observation, state, episode_start, deterministic)``: for
    a deterministic action of a covered actor (module docstring) its float64 evaluation, the
    same bits on every machine (float32, clipped to the action space, batched as given);
    otherwise SB3's own."""
    policy = getattr(model, "policy", None)  # any object with SB3's predict runs as it is
    layers = _actor(policy) if deterministic else None
    if layers is None:
        return model.predict(observation, state, episode_start, deterministic)
    obs = np.asarray(observation)
    space = policy.observation_space
    batched = obs.shape != space.shape
    mean = actor_mean(layers, obs.reshape(-1, *space.shape))
    actions = mean.reshape(-1, *policy.action_space.shape)
    actions = np.clip(actions, policy.action_space.low, policy.action_space.high)
    actions = actions.astype(np.float32)
    return (actions if batched else actions[0]), state
