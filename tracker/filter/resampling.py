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
