"""Resampling trigger and corrected systematic resampling (spec section 4.4, corrected Algorithm 3)."""

from __future__ import annotations

import math

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


@nb.njit(cache=True)
def _block_sum(a: np.ndarray, lo: int, n: int) -> float:
    """numpy's sum of ``a[lo:lo + n]`` for n <= 128 (:func:`pairwise_sum`)."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    end = n - n % 8
    while i < end:
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@nb.njit(cache=True)
def pairwise_sum(a: np.ndarray, lo: int, n: int) -> float:
    """Sum of ``a[lo:lo + n]`` (float64) as numpy's ``sum`` forms it for a contiguous float64 array: in order below 8
    terms, eight running sums (then combined as a tree, the rest added in order) up to 128 terms, above that the two
    halves (the first a multiple of 8 long) summed alike and added. The same value bit for bit. (numpy's recursion
    walked with an explicit stack: numba's cache does not take recursive functions.)"""
    if n <= 128:
        return _block_sum(a, lo, n)
    seg_lo = np.empty(64, np.int64)
    seg_n = np.empty(64, np.int64)
    stage = np.empty(64, np.int64)
    vals = np.empty(64)
    top, nv = 0, 0
    seg_lo[0], seg_n[0], stage[0] = lo, n, 0
    while top >= 0:
        m = seg_n[top]
        if m <= 128:
            vals[nv] = _block_sum(a, seg_lo[top], m)
            nv += 1
            top -= 1
            continue
        n2 = m // 2
        n2 -= n2 % 8
        if stage[top] == 0:  # the first half
            stage[top] = 1
            seg_lo[top + 1], seg_n[top + 1], stage[top + 1] = seg_lo[top], n2, 0
            top += 1
        elif stage[top] == 1:  # the second half
            stage[top] = 2
            seg_lo[top + 1], seg_n[top + 1], stage[top + 1] = seg_lo[top] + n2, m - n2, 0
            top += 1
        else:  # both done: their sum
            vals[nv - 2] = vals[nv - 2] + vals[nv - 1]
            nv -= 1
            top -= 1
    return vals[0]


@nb.njit(cache=True)
def reweigh(log_w: np.ndarray, ell_tot: np.ndarray, ell_prev: np.ndarray, w: np.ndarray) -> float:
    """One coordinate pass's weight update in place (all (N,) float64): ``log_w += ell_tot − ell_prev``, the
    normalised weights into ``w`` (:func:`normalize_log_weights`), ``log_w`` ← ``log(max(w, 1e-300))``; returns
    D_KL(w‖U) (:func:`kl_from_uniform`). numpy's operations in its order (sums as :func:`pairwise_sum`): the same
    values as that numpy form, bit for bit where numpy's exp and log round as the C library's (within a few units in
    the last place on CPUs where numpy uses its AVX-512 forms of them)."""
    n = log_w.shape[0]
    m = -np.inf
    nan = False
    for j in range(n):
        log_w[j] += ell_tot[j] - ell_prev[j]
        x = log_w[j]
        if x != x:
            nan = True
        elif x > m:
            m = x
    if nan or not np.isfinite(m):
        for j in range(n):
            w[j] = 1.0 / n
    else:
        for j in range(n):
            w[j] = math.exp(log_w[j] - m)
        total = pairwise_sum(w, 0, n)
        for j in range(n):
            w[j] = w[j] / total
    terms = np.empty(n)
    k = 0
    for j in range(n):
        wj = w[j]
        log_w[j] = math.log(wj if wj >= 1e-300 else 1e-300)
        if wj > 0.0:
            terms[k] = wj * math.log(wj)
            k += 1
    return pairwise_sum(terms, 0, k) + math.log(n)


def systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices (N,) of systematic (low-variance) resampling.

    C_j = Σ_{n≤j} w_n, u_1 ~ U(0, 1/N), u_i = u_1 + (i−1)/N, a(i) = smallest j with C_j ≥ u_i. The caller copies
    everything attached to particle a(i) into slot i and resets all weights to 1/N. One kernel
    (:func:`_systematic_indices`) forms :func:`systematic_resample_numpy`'s values (its draw taken first).
    """
    w = np.ascontiguousarray(weights, np.float64).reshape(-1)
    if w.size == 0:
        raise ValueError("no particles to resample")
    idx, ok = _systematic_indices(w, rng.random())
    if not ok:
        raise ValueError("weights must be finite and sum to a positive value")
    return idx


def systematic_resample_numpy(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """:func:`systematic_resample` in numpy (the reference its kernel is tested against)."""
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
def _systematic_indices(w: np.ndarray, u0: float) -> tuple[np.ndarray, bool]:
    """The indices of :func:`systematic_resample_numpy` for the draw ``u0``, and False (no indices) when the weights
    do not sum to a finite positive value: the total as numpy's ``sum`` forms it (:func:`pairwise_sum`), the running
    sums of ``w / total`` in order (``np.cumsum``), the last set to 1, and for each ``u_i = (u0 + i) / n`` the first
    running sum ``>= u_i`` (``np.searchsorted`` ``left``; the keys rise, so one forward sweep finds them all)."""
    n = w.shape[0]
    total = pairwise_sum(w, 0, n)
    if not (np.isfinite(total) and total > 0.0):
        return np.empty(0, np.int64), False
    c = np.empty(n)
    acc = 0.0
    for j in range(n):
        acc += w[j] / total
        c[j] = acc
    c[n - 1] = 1.0
    idx = np.empty(n, np.int64)
    j = 0
    for i in range(n):
        u = (u0 + float(i)) / n
        while j < n and c[j] < u:
            j += 1
        idx[i] = j
    return idx, True


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
