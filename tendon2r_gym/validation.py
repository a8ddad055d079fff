"""Validation helpers shared by every public input: one wording for every ValueError.

Each error names the field, the bad value and what is allowed.  Numbers accept Python and numpy
ints and floats (``np.float32(0.014)`` is a number); bools are never numbers.
"""

from __future__ import annotations

import difflib
import math
import numbers
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np


def invalid(field: str, value: Any, allowed: str) -> ValueError:
    """Returns the project's ValueError: ``<field> = <value> is invalid; allowed: <allowed>``."""
    return ValueError(f"{field} = {value!r} is invalid; allowed: {allowed}")


def invalid_field(error: ValueError) -> str:
    """Returns the field that an `invalid` error names, without its class prefix
    (``Mechanism.tendon_damping``: ``tendon_damping``)."""
    return str(error).split(" = ", 1)[0].rsplit(".", 1)[-1]


def is_number(value: Any) -> bool:
    """Returns whether ``value`` is a real number (numpy scalars included, bools excluded)."""
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def number(
    field: str,
    value: Any,
    lo: float = -math.inf,
    hi: float = math.inf,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
) -> float:
    """Returns ``value`` as a float, or raises if it is not a finite number in [lo, hi] (an open
    bound with ``lo_open`` / ``hi_open``)."""
    lo_txt = f"{'(' if lo_open else '['}{lo:g}" if math.isfinite(lo) else "(-inf"
    hi_txt = f"{hi:g}{')' if hi_open else ']'}" if math.isfinite(hi) else "inf)"
    allowed = f"a finite number in {lo_txt}, {hi_txt}"
    if not is_number(value):
        raise invalid(field, value, allowed)
    x = float(value)
    if not math.isfinite(x) or x < lo or x > hi or (lo_open and x == lo) or (hi_open and x == hi):
        raise invalid(field, value, allowed)
    return x + 0.0  # -0.0 is 0.0


def integer(field: str, value: Any, lo: int, hi: int) -> int:
    """Returns ``value`` as an int, or raises if it is not an integer in [lo, hi] (numpy
    integers accepted, bools and floats refused)."""
    if not isinstance(value, (numbers.Integral,)) or isinstance(value, (bool, np.bool_)):
        raise invalid(field, value, f"an integer in [{lo}, {hi}]")
    if not lo <= int(value) <= hi:
        raise invalid(field, value, f"an integer in [{lo}, {hi}]")
    return int(value)


def boolean(field: str, value: Any) -> bool:
    """Returns ``value`` if it is a bool (numpy bools included), or raises."""
    if not isinstance(value, (bool, np.bool_)):
        raise invalid(field, value, "true or false")
    return bool(value)


def subset(field: str, value: Any, allowed: Sequence[str]) -> tuple[str, ...]:
    """Returns ``value``, a list (or tuple or array) of distinct names from ``allowed``, as a
    tuple in ``allowed``'s order, or raises."""
    names = value.tolist() if isinstance(value, np.ndarray) else value
    ok = isinstance(names, (list, tuple)) and all(isinstance(n, str) for n in names)
    if not ok or len(set(names)) != len(names) or not set(names) <= set(allowed):
        shown = names if isinstance(names, (list, tuple)) else value
        raise invalid(field, shown, f"a list of distinct names from {list(allowed)}")
    return tuple(n for n in allowed if n in names)


def choice(field: str, value: Any, allowed: Iterable[Any]) -> Any:
    """Returns ``value`` if it is one of ``allowed`` (compared by type and equality: an array,
    a list or ``1`` for ``True`` is not a choice), or raises."""
    options = tuple(allowed)
    same = lambda o: isinstance(value, type(o)) and isinstance(value, bool) == isinstance(o, bool)  # noqa: E731
    if not any(same(o) and value == o for o in options):
        raise invalid(field, value, f"one of {options}")
    return value


def mapping(field: str, value: Any) -> dict[str, Any]:
    """Returns ``value`` as a dict, or raises if it is not a mapping (None is an empty one)."""
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise invalid(field, value, "a mapping of field names to values")
    return dict(value)


def check_keys(where: str, given: Iterable[str], allowed: Iterable[str]) -> None:
    """Raises for the first key of ``given`` not in ``allowed``, naming the closest allowed
    key and all of them."""
    allowed = list(allowed)
    for key in given:
        if key not in allowed:
            close = difflib.get_close_matches(str(key), [str(a) for a in allowed], n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(
                f"{where}: unknown key {key!r}{hint} allowed: {sorted(map(str, allowed))}"
            )


def pair(
    field: str,
    value: Any,
    lo: float = -math.inf,
    hi: float = math.inf,
    names: str = "joint A, joint B",
) -> tuple[float, float]:
    """Returns ``value`` (a list, tuple or numpy array of two) as two floats, each finite and in
    [lo, hi]; ``names`` says what the two are in the error."""
    allowed = f"[{names}], two finite numbers each in [{lo:g}, {hi:g}]"
    if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, Iterable):
        raise invalid(field, value, allowed)
    items = list(value)
    if len(items) != 2 or not all(is_number(v) for v in items):
        raise invalid(field, value, allowed)
    out = tuple(float(v) for v in items)
    if not all(math.isfinite(v) and lo <= v <= hi for v in out):
        raise invalid(field, value, allowed)
    return out  # type: ignore[return-value]


def real_array(field: str, value: Any, shape: tuple[int, ...], allowed: str) -> np.ndarray:
    """Returns ``value`` as a float64 array of ``shape`` with finite entries, or raises naming
    ``field`` (strings, mappings, complex numbers and bools are refused)."""
    try:
        arr = np.asarray(value)
    except Exception:  # noqa: BLE001 (anything numpy cannot read is invalid)
        raise invalid(field, value, allowed) from None
    if arr.dtype.kind not in "fiu" or arr.shape != shape:
        raise invalid(field, value, allowed)
    arr = arr.astype(np.float64)
    if not np.isfinite(arr).all():
        raise invalid(field, value, allowed)
    return arr
