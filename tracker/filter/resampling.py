"""Resampling trigger and corrected systematic resampling (spec section 4.4, corrected Algorithm 3)."""

from __future__ import annotations

import numba as nb
import numpy as np


def normalize_log_weights(log_w: np.ndarray) -> np.ndarray:
    """Normalised weights (N,) from log weights, computed stably (max subtracted)."""
    log_w = np.asarray(log_w, np.float64)
    if log_w.size == 0:
        raise ValueError("no particles")
    m = np.max(log_w)
    if not np.isfinite(m):
        return np.full(log_w.shape, 1.0 / log_w.size)
    w = np.exp(log_w - m)
    return w / w.sum()


def kl_from_uniform(weights: np.ndarray) -> float:
    """D_KL(P‖U) = Σ w log w + log N (natural log), 0 ≤ D_KL ≤ log N (eqs 4.14–4.16)."""
    w = np.asarray(weights, np.float64)
    nz = w[w > 0]
    return float(np.sum(nz * np.log(nz)) + np.log(w.size))


def systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices (N,) of systematic (low-variance) resampling.

    C_j = Σ_{n≤j} w_n, u_1 ~ U(0, 1/N), u_i = u_1 + (i−1)/N, a(i) = smallest j with C_j ≥ u_i. The caller copies
    everything attached to particle a(i) into slot i and resets all weights to 1/N.
    """
    w = np.asarray(weights, np.float64)
    n = w.size
    if n == 0:
        raise ValueError("no particles to resample")
    total = w.sum()
    if not np.isfinite(total) or total <= 0:
        raise ValueError("weights must be finite and sum to a positive value")
    c = np.cumsum(w / total)
    c[-1] = 1.0
    u = (rng.random() + np.arange(n)) / n
    return np.searchsorted(c, u, side="left").astype(np.int64)


@nb.njit(cache=True)
def take_rows(src: np.ndarray, idx: np.ndarray, out: np.ndarray) -> None:
    """``out[i] = src[idx[i]]`` for 2-D arrays (rows), without allocating."""
    m = src.shape[1]
    for i in range(idx.shape[0]):
        r = idx[i]
        for c in range(m):
            out[i, c] = src[r, c]


@nb.njit(cache=True)
def take_rows_inplace(a: np.ndarray, idx: np.ndarray) -> None:
    """``a[:] = a[idx]`` for a 2-D array ``a`` (rows), in place, copying only the rows that change.

    With ``idx`` non-decreasing (as :func:`systematic_resample` returns it) no extra storage is needed: rows whose
    source lies after them are filled front to back, then rows whose source lies before them back to front (a
    source row is never overwritten before it is read: a row ``r`` filled in the first sweep has ``idx[r] > r``, so
    no later row ``j > r`` can take from it, ``idx[j] >= idx[r] > r``). Other ``idx`` go through a copy of the
    rows."""
    n = idx.shape[0]
    ordered = True
    for j in range(1, n):
        if idx[j] < idx[j - 1]:
            ordered = False
            break
    m = a.shape[1]
    if not ordered:
        src = a[idx].copy()
        for j in range(n):
            for c in range(m):
                a[j, c] = src[j, c]
        return
    for j in range(n):
        r = idx[j]
        if r > j:
            for c in range(m):
                a[j, c] = a[r, c]
    for j in range(n - 1, -1, -1):
        r = idx[j]
        if r < j:
            for c in range(m):
                a[j, c] = a[r, c]
