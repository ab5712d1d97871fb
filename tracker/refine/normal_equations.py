"""Numba helpers shared by the refinement's residual kernels (depth: :mod:`tracker.refine.dense_depth`,
silhouette: :mod:`tracker.refine.region_term`): one residual's Jacobian row for a twist about a centre, and its
Huber-weighted contribution to the normal equations."""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, inline="always")
def twist_row(J: np.ndarray, x0: float, x1: float, x2: float, c: np.ndarray, d0: float, d1: float,
              d2: float) -> None:
    """Fill ``J`` (6,) with the derivative of a residual whose gradient in the camera-frame point x = (x0, x1, x2)
    is d = (d0, d1, d2), for the twist (ω, v) about ``c`` (x ← c + exp(ω)(x − c) + v): J = [(x − c) × d, d]."""
    a0, a1, a2 = x0 - c[0], x1 - c[1], x2 - c[2]
    J[0] = a1 * d2 - a2 * d1
    J[1] = a2 * d0 - a0 * d2
    J[2] = a0 * d1 - a1 * d0
    J[3] = d0
    J[4] = d1
    J[5] = d2


@nb.njit(cache=True, inline="always")
def add_huber(H: np.ndarray, g: np.ndarray, J: np.ndarray, r: float, sigma: float, huber_k: float,
              scale: float) -> None:
    """Add the residual ``r`` with row ``J`` to the upper triangle of ``H`` and to ``g``, Huber-weighted at scale
    ``sigma`` (threshold ``huber_k`` σ) and multiplied by ``scale``/σ²."""
    rs = abs(r) / sigma
    wgt = (1.0 if rs <= huber_k else huber_k / rs) * scale / (sigma * sigma)
    for a in range(6):
        g[a] += wgt * r * J[a]
        for b in range(a, 6):
            H[a, b] += wgt * J[a] * J[b]
