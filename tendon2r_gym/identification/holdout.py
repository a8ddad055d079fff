"""Checks of a fit on held-out pieces of the recordings (cross-validation).

The intervals of tendon2r_gym.identification.identify assume that the model is right: a field
left out of the fit that is off (a motor mass guessed 35% low), or an excitation the model
follows poorly, shifts the fit without widening them.  Two cheap checks catch part of it,
reusing the pieces the fit already cut and no new fit:

- **Folds of the final fit.**  The pieces are split into FOLDS contiguous blocks (neighbouring
  pieces share the excitation's content, and a model error shows as blocks that want other
  values).  Each fold is fitted on the other blocks by one Gauss-Newton step from the fit,
  with the fit's own Jacobian, and replayed on every piece (one batched rollout).  A field
  whose fold fits move further than its interval has it widened to hold them all; where the
  held-out pieces' residual is more than HOLDOUT_RATIO times the in-sample one, the fit does
  not predict the recording, and every field is flagged.
- **Folds of the delay.**  The subset's pieces, in FOLDS blocks, each choose the loop delay
  whose fit misses them least.  Delays chosen by some block are not told apart from the best
  one (the delay, the lag and the cables' stretch trade off).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from tendon2r_gym.identification.fit import ANGLE_UNIT
from tendon2r_gym.identification.problem import Problem

#: Contiguous blocks of pieces, each held out once.
FOLDS = 4
#: A held-out residual (RMS) this many times the in-sample one: the fit does not predict
#: the held-out pieces.
HOLDOUT_RATIO = 1.5


class Holdout(NamedTuple):
    """What the folds of the final fit found (scaled fields)."""

    fits: np.ndarray  # (folds, fields): each fold's fit
    spread: np.ndarray  # (fields,): the largest move of a fold's fit from the fit
    in_rms_rad: float  # the folds' residual on the pieces they were fitted on
    out_rms_rad: float  # and on the pieces they held out

    @property
    def ratio(self) -> float:
        """Held-out over in-sample residual (RMS); about 1 where the model is right."""
        return self.out_rms_rad / max(self.in_rms_rad, 1e-300)

    @property
    def predicts(self) -> bool:
        return self.ratio <= HOLDOUT_RATIO


def blocks(n: int, folds: int = FOLDS) -> list[np.ndarray]:
    """Splits ``n`` pieces into at most ``folds`` contiguous blocks of near-equal size."""
    return [b for b in np.array_split(np.arange(n), min(folds, n)) if b.size]


def cross_validate(prob: Problem, x: np.ndarray, J: np.ndarray, r: np.ndarray) -> Holdout:
    """Folds the fit ``x`` on the current pieces (module docstring): ``J`` and ``r`` are its
    Jacobian (rows, fields) and residual (rows), rows grouped by piece."""
    P, n = len(prob.rep.pieces), len(prob.names)
    rows = r.size // P
    lo = np.array([prob.box[k][0] / prob.box[k][2] for k in prob.names])
    hi = np.array([prob.box[k][1] / prob.box[k][2] for k in prob.names])
    parts = blocks(P)
    fits = np.empty((len(parts), n))
    for k, held in enumerate(parts):
        train = np.ones(P, bool)
        train[held] = False
        mask = np.repeat(train, rows)
        step = np.linalg.lstsq(J[mask], -r[mask], rcond=None)[0] if n else np.zeros(0)
        fits[k] = np.clip(x + step, lo, hi)
    replayed = prob.residual(fits.T)[0][0].reshape(P, rows, len(parts))
    sq_in = sq_out = 0.0
    for k, held in enumerate(parts):
        per_piece = np.sum(replayed[:, :, k] ** 2, axis=1)
        sq_out += float(per_piece[held].sum())
        sq_in += float(per_piece.sum() - per_piece[held].sum())
    count_out = rows * P
    count_in = rows * P * max(len(parts) - 1, 1)
    return Holdout(
        fits=fits,
        spread=np.max(np.abs(fits - x), axis=0) if n else np.zeros(0),
        in_rms_rad=float(np.sqrt(sq_in / count_in)) * ANGLE_UNIT,
        out_rms_rad=float(np.sqrt(sq_out / count_out)) * ANGLE_UNIT,
    )


def fold_delays(per_piece: dict[int, np.ndarray], folds: int = FOLDS) -> set[int]:
    """Returns the loop delays that some block of the subset's pieces fits best: each
    delay's fitted residual per piece (``per_piece``), summed over each of ``folds``
    contiguous blocks."""
    delays = sorted(per_piece)
    costs = np.stack([per_piece[d] for d in delays])  # (delays, pieces)
    return {delays[int(np.argmin(costs[:, b].sum(axis=1)))] for b in blocks(costs.shape[1], folds)}
