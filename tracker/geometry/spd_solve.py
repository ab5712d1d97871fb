"""Compiled solve of small symmetric positive definite systems (the Gauss-Newton normal equations of the rigid
refinements: :mod:`tracker.refine.dense_depth`, :mod:`tracker.geometry.projective_icp`).

Unitless: the caller's units (rotation in rad, translation in m for a 6-DoF update).
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def solve_spd6(A, b):
    """x with ``A x = b`` for a symmetric positive definite 6×6 ``A`` (Cholesky, lower triangle read); ``ok`` False
    (and x zero) when A is not positive definite."""
    L = np.zeros((6, 6))
    x = np.zeros(6)
    for i in range(6):
        for j in range(i + 1):
            acc = A[i, j]
            for m in range(j):
                acc -= L[i, m] * L[j, m]
            if i == j:
                if not acc > 0.0:
                    return x, False
                L[i, i] = np.sqrt(acc)
            else:
                L[i, j] = acc / L[j, j]
    y = np.zeros(6)
    for i in range(6):
        acc = b[i]
        for m in range(i):
            acc -= L[i, m] * y[m]
        y[i] = acc / L[i, i]
    for i in range(5, -1, -1):
        acc = y[i]
        for m in range(i + 1, 6):
            acc -= L[m, i] * x[m]
        x[i] = acc / L[i, i]
    return x, True
