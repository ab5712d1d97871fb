"""Mutual exclusion of two hand tracks (product addition, ``HandTrackerConfig.exclusion``): an interaction
potential between the tracks' particle filters, in the manner of the MRF motion prior of Khan, Balch and Dellaert
(2005) and MacCormick and Blake's probabilistic exclusion principle (1999): one hand cannot be two tracks.

Two hands of one person have the same skin colour, so where the hand on top slides over the other, the lower hand's
track sees its box fill with the top hand's skin and flow, and follows the top hand: both tracks end on one hand
("coalescence"). Two real palm boxes almost never coincide: on the ground truth of tuning seeds 0–4 of ``hands-s2``
the two palm boxes have a box F-score above 0.6 in 2 % of the frames with both hands (60 of 3072), while the two
tracks' estimates did in 10 % (321, 195 of them where the true boxes score below 0.3).

So each particle's weight is multiplied by ψ = exp(−:data:`KAPPA` · max(0, F − :data:`F0`)), F the box F-score of
the particle's box with the other track's predicted box (its last estimate moved by its velocity); particles of the
other hand's box lose weight against those that stayed on their own hand's visible part.

Off by default (``HandTrackerConfig.exclusion``): on tuning seeds 0–4 of ``hands-s2`` (with the group box of
:mod:`tracker.hands.group_box`) it helped on filter seeds 0–3 (F̄^b 0.714 → 0.744) and hurt on 4–7 (0.744 → 0.719):
once two tracks are on each other's hands it keeps them there. Units: working pixels.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from tracker.hands.box_stats import box_of

F0 = 0.5
"""Box F-score with another track's box above which a particle is penalised."""
KAPPA = 10.0
"""Rate of the penalty per unit of F-score above F0 (at F = 1 the weight is multiplied by e^−5)."""


@nb.njit(cache=True, nogil=True)
def exclusion_factors(parts: np.ndarray, others: np.ndarray, f0: float, kappa: float) -> np.ndarray:
    """ψ per particle: ``parts`` [N, ≥4] states (x, y, w, h, …), ``others`` [M, 4] inclusive boxes (u0, v0, u1, v1)
    of the other tracks; ψ = exp(−kappa · max(0, F − f0)) with F the largest box F-score (inclusive integer boxes,
    :func:`tracker.hands.box_stats.box_of`) of the particle's box with any of them; 1 without others."""
    n = parts.shape[0]
    out = np.ones(n)
    for i in range(n):
        u0, v0, u1, v1 = box_of(parts[i, 0], parts[i, 1], parts[i, 2], parts[i, 3])
        sa = (u1 - u0 + 1) * (v1 - v0 + 1)
        best = 0.0
        for j in range(others.shape[0]):
            b0, b1, b2, b3 = others[j, 0], others[j, 1], others[j, 2], others[j, 3]
            iw = min(u1, b2) - max(u0, b0) + 1
            ih = min(v1, b3) - max(v0, b1) + 1
            sb = (b2 - b0 + 1) * (b3 - b1 + 1)
            if iw > 0 and ih > 0 and sa + sb > 0:
                f = 2.0 * iw * ih / (sa + sb)
                if f > best:
                    best = f
        if best > f0:
            out[i] = np.exp(-kappa * (best - f0))
    return out


def predicted_box(state: np.ndarray) -> tuple[int, int, int, int]:
    """Inclusive box of a state moved by its velocity (x + x', y + y'), working px."""
    return box_of(float(state[0] + state[4]), float(state[1] + state[5]), float(state[2]), float(state[3]))
