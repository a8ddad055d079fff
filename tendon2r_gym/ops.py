"""Elementwise operations for formulas written once and run on Python floats or numpy arrays.

The env's formulas (tendon2r_gym.envs.formulas) and the moment-arm condition number are written
as plain arithmetic with the few functions below passed in: `SCALAR` (``math``, for the single
env, where scalar math on two joints is several times faster than numpy) or `BATCH`
(numpy over N arms, for the vector env).  Both give the same bits: numpy's float64 sin and cos
round as ``math``'s do on this platform (tests/test_vector_env.py compares whole episodes),
and `_log1p` maps ``math.log1p`` because numpy's SIMD log1p may differ in the last bit.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Ops:
    """The elementwise functions a shared formula may call."""

    sin: Callable[[Any], Any]
    cos: Callable[[Any], Any]
    log1p: Callable[[Any], Any]
    sqrt: Callable[[Any], Any]
    copysign: Callable[[Any, Any], Any]
    maximum: Callable[[Any, Any], Any]
    isfinite: Callable[[Any], Any]
    not_: Callable[[Any], Any]
    where: Callable[[Any, Any, Any], Any]  # where(cond, if_true, if_false)


def _log1p(x: np.ndarray) -> np.ndarray:
    """math.log1p on every entry (bit for bit as the scalar path)."""
    x = np.asarray(x, dtype=np.float64)
    return np.fromiter(map(math.log1p, x.ravel().tolist()), float, x.size).reshape(x.shape)


SCALAR = Ops(
    sin=math.sin,
    cos=math.cos,
    log1p=math.log1p,
    sqrt=math.sqrt,
    copysign=math.copysign,
    maximum=max,
    isfinite=math.isfinite,
    not_=operator.not_,
    where=lambda cond, a, b: a if cond else b,
)
BATCH = Ops(
    sin=np.sin,
    cos=np.cos,
    log1p=_log1p,
    sqrt=np.sqrt,
    copysign=np.copysign,
    maximum=np.maximum,
    isfinite=np.isfinite,
    not_=np.logical_not,
    where=np.where,
)
