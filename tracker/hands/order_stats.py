"""Order statistics of the hand step without numpy's quantile/median machinery (product speed-up, outputs equal).

``np.quantile`` and ``np.median`` spend most of their time on argument handling (NaN checks, axis moves, the
interpolation's general array path) for the few hundred to few thousand values the palm anchors pass them per arm,
several times per frame. The functions here do one ``np.partition`` and return exactly what the numpy calls they
replace return for finite 1-D input (tested in ``tests/test_hands_kernels.py`` against numpy): the same median value
and dtype arithmetic, and the same value as ``np.quantile(x, q)`` with numpy's default ('linear') method.

Units: whatever the input's (metres of depth, working pixels of distance).
"""

from __future__ import annotations

import math

import numpy as np


def median(x: np.ndarray) -> float:
    """``float(np.median(x))`` for a non-empty finite 1-D array: the middle value, or the mean of the two middle
    values computed in the array's dtype as numpy does ((a + b) / 2)."""
    n = len(x)
    h = n // 2
    if n % 2:
        return float(np.partition(x, h)[h])
    part = np.partition(x, (h - 1, h))
    return float((part[h - 1] + part[h]) / 2)


def quantile(x: np.ndarray, q: float) -> float:
    """``float(np.quantile(x, q))`` (numpy's default 'linear' method) for a non-empty finite 1-D float64 array and
    0 <= q <= 1: with v = (n − 1)·q, i = floor(v), the sorted values a[i], a[i + 1] interpolated by t = v − i with
    numpy's two-sided formula (a + (b − a)·t below t = 0.5, b − (b − a)·(1 − t) from it), so the value is
    bit-identical and ``x >= quantile(x, q)`` selects what numpy's threshold selects."""
    n = len(x)
    v = (n - 1) * q
    if v >= n - 1:
        return float(np.max(x))
    i = int(math.floor(v))
    part = np.partition(x, (i, i + 1))
    a, b = float(part[i]), float(part[i + 1])
    t = v - i
    diff = b - a
    return a + diff * t if t < 0.5 else b - diff * (1.0 - t)
