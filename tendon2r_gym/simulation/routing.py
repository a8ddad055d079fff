"""Tendon routings: which side of each pulley every tendon takes, its nominal moment arms, and
whether pull-only tendons can drive both joints.  Pure numpy: no MuJoCo, no other module of the
package, so the mechanism, the model and the actuation all read routing knowledge from here.

A tendon passes each pulley on side +1 (over the top, +z in the link frame) or -1 (under).  Side
0 on pulley 2 means the tendon ends on link c and spans joint A only.  The moment arms of a
straight tendon are dL/dq = (-s1 r1, -s2 r2).  Pull-only tendons produce any joint torque exactly
when their moment arms *positively span* the torque plane (`positive_span`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np

Sides = tuple[tuple[int, ...], ...]

#: Named routings: the side (+1 over, -1 under, 0 not reached) each tendon takes on
#: (pulley 1, pulley 2).  A new routing is one entry here (and its test).
ROUTINGS: dict[str, Sides] = {
    # Not mirror images: the moment-arm matrix is full rank, both joints are actuated.
    "asymmetric": ((+1, +1), (-1, +1)),
    # The reports' text: tendon 1 over both pulleys, tendon 2 under both (rank 1 at q = 0).
    "parallel": ((+1, +1), (-1, -1)),
    # The course XML template: tendon 1 under pulley 1 and over pulley 2, tendon 2 the reverse.
    "crossed": ((-1, +1), (+1, -1)),
    # Three tendons for pull-only motors: moment arms (-r1, -r2), (-r1, +r2) and (+r1, 0), whose
    # null vector (1, 1, 2) is strictly positive, so a pretension keeps every tendon taut.  The
    # third tendon ends on link c: with three tendons that all wrap both pulleys, the rows are
    # corners (+-r1, +-r2) and the origin lies on an edge of their triangle (no strictly
    # positive pretension exists).
    "n_plus_1": ((+1, +1), (+1, -1), (-1, 0)),
}

ALLOWED = (
    f"one of {sorted(ROUTINGS)}, or 2 or more (s1, s2) pairs: s1 in {{-1, +1}} on pulley 1, "
    "s2 in {-1, 0, +1} on pulley 2 (0: the tendon ends on link c)"
)


def normalize(routing: object) -> str | Sides | None:
    """Returns a routing name or exact integer sides, or None if ``routing`` is neither."""
    if isinstance(routing, str):
        return routing if routing in ROUTINGS else None
    try:
        rows = [list(tendon) for tendon in routing]  # type: ignore[union-attr]
    except TypeError:
        return None
    if len(rows) < 2 or any(len(t) != 2 for t in rows):
        return None
    # Exact integers only: 1.5 must not be truncated to 1; bools are not sides.
    numeric = all(
        isinstance(s, (int, float, np.integer, np.floating)) and not isinstance(s, bool)
        for t in rows
        for s in t
    )
    if not numeric or not all(s in (-1, 0, 1) for t in rows for s in t):
        return None
    if any(t[0] == 0 for t in rows):  # it would end on the wall and span no joint
        return None
    return tuple(tuple(int(s) for s in t) for t in rows)


def sides_of(routing: str | Sides) -> Sides:
    """Returns the sides of a (normalized) routing."""
    return ROUTINGS[routing] if isinstance(routing, str) else routing


def nominal_moment_arms(sides: Sequence[Sequence[int]], r1: float, r2: float) -> np.ndarray:
    """Returns the moment arms of straight tendons on the pulleys: rows (-s1 r1, -s2 r2)."""
    return np.array([(-s1 * r1, -s2 * r2) for s1, s2 in sides], dtype=np.float64)


def positive_span(J: np.ndarray) -> tuple[bool, float]:
    """Returns (whether the rows of J positively span the plane, margin in rad).

    Pulling tendons can produce any joint torque exactly when their rows leave no angular gap
    of pi or more: the margin is pi minus the largest gap between consecutive row directions
    (> 0 when they span; for two tendons it is at most 0)."""
    rows = [r for r in np.asarray(J, dtype=np.float64).reshape(-1, 2) if np.hypot(*r) > 1e-12]
    if len(rows) < 3:
        return False, min(0.0, math.pi - _max_gap(rows)) if rows else -math.pi
    margin = math.pi - _max_gap(rows)
    return margin > 1e-9, margin


def _max_gap(rows: Sequence[np.ndarray]) -> float:
    angles = sorted(math.atan2(r[1], r[0]) for r in rows)
    gaps = [b - a for a, b in itertools.pairwise(angles)]
    return max([*gaps, 2 * math.pi - (angles[-1] - angles[0])])


def positive_span_of_sides(
    sides: Sequence[Sequence[int]], r1: float, r2: float
) -> tuple[bool, str]:
    """Returns whether a routing's nominal moment arms positively span, and why not."""
    if len(sides) < 3:
        return False, (
            f"{len(sides)} pull-only tendons cannot reverse a joint torque; they need n + 1 = 3 "
            "tendons whose moment arms positively span the torque plane"
        )
    spans, margin = positive_span(nominal_moment_arms(sides, r1, r2))
    if not spans:
        return False, (
            f"its moment arms do not positively span the torque plane (margin {margin:.3g} "
            "rad); tendons that wrap both pulleys give corners (+-r1, +-r2), which span only on "
            "the boundary: add a tendon that ends on link c (side 0 on pulley 2)"
        )
    return True, ""


def null_direction(J: np.ndarray) -> np.ndarray | None:
    """Returns a unit null vector n of J^T with every entry > 0, or None if none exists.

    Three tendons have a one-dimensional null space (the cross product of J's columns); more
    tendons use the sum of the positive null vectors of every spanning triple."""
    J = np.asarray(J, dtype=np.float64)
    total = np.zeros(len(J))
    for idx in itertools.combinations(range(len(J)), 3):
        sub = J[list(idx)]
        n = np.cross(sub[:, 0], sub[:, 1])
        if np.all(n > 0) or np.all(n < 0):
            total[list(idx)] += np.abs(n) / np.linalg.norm(n)
    if not np.all(total > 0):
        return None
    return total / np.linalg.norm(total)
