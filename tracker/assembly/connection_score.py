"""Connection score and particle allocation (spec section 10, eqs 5.15–5.19)."""

from __future__ import annotations

import numpy as np

from tracker.assembly.relations import margins


def score_distance(p1: np.ndarray, p2: np.ndarray, m_p, K: float) -> float:
    """``d(p1, p2)`` of eq. 5.16: 1 while the summed squared normalised error is ≤ 3, growing beyond."""
    e = (np.asarray(p1, float) - np.asarray(p2, float)) / margins(m_p)
    return float(np.sqrt(max(0.0, K * (float(e @ e) - 3.0)) + 1.0))


def connection_score(
    p_des: np.ndarray, R_des: np.ndarray, p_real: np.ndarray, R_real: np.ndarray, m_p, K: float
) -> float:
    """Score in (0, 1] of eq. 5.15, averaging both viewing directions (eqs 5.17–5.18).

    ``p_*`` is the second part's position in the first part's frame, ``R_*`` the relative rotation
    (both already corrected for cube symmetry). The reverse terms are ``p' = −Rᵀ p``.
    """
    p_des, p_real = np.asarray(p_des, float), np.asarray(p_real, float)
    p_des_rev = -np.asarray(R_des, float).T @ p_des
    p_real_rev = -np.asarray(R_real, float).T @ p_real
    return 0.5 * (1.0 / score_distance(p_des, p_real, m_p, K) + 1.0 / score_distance(p_des_rev, p_real_rev, m_p, K))


def allocate_particles(score: float, n_max: int) -> int:
    """``N_k = round(score · N_max)`` (eq. 5.19, nearest-integer rounding as the text defines)."""
    return int(np.floor(score * n_max + 0.5))
