"""Pixel boxes of the hand tracker: a filter state's box, clipping, and the overlap measures the
track logic uses (:mod:`tracker.hands.tracker`).

A *state* is ``[x, y, w, h, vx, vy]`` (box centre, width and height in pixels, spec §2); an *inclusive* box is
``(u0, v0, u1, v1)`` with its last pixels included; an *end-exclusive* box ``[u0, v0, u1, v1]`` ends one past them.
Pixels of the tracker's working resolution.
"""

from __future__ import annotations

import numpy as np

from tracker.hands.box_stats import box_area, box_of


def state_box(state: np.ndarray) -> tuple[int, int, int, int]:
    """Inclusive integer box of a state (spec §2)."""
    return box_of(float(state[0]), float(state[1]), float(state[2]), float(state[3]))


def clipped_box(state: np.ndarray, size: tuple[int, int]) -> list[int]:
    """End-exclusive box of a state clipped to the image (empty boxes have u1 ≤ u0 or v1 ≤ v0)."""
    u0, v0, u1, v1 = state_box(state)
    W, H = size
    return [max(u0, 0), max(v0, 0), min(u1 + 1, W), min(v1 + 1, H)]


def box_f_score(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> float:
    """Dice coefficient of two inclusive boxes (areas in pixels)."""
    iw = min(a[2], b[2]) - max(a[0], b[0]) + 1
    ih = min(a[3], b[3]) - max(a[1], b[1]) + 1
    inter = max(iw, 0) * max(ih, 0)
    sa, sb = box_area(a), box_area(b)
    return 2.0 * inter / (sa + sb) if sa + sb > 0 else 0.0


def inside_fraction(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> float:
    """Fraction of inclusive box a's area that lies inside inclusive box b."""
    iw = min(a[2], b[2]) - max(a[0], b[0]) + 1
    ih = min(a[3], b[3]) - max(a[1], b[1]) + 1
    area = box_area(a)
    return max(iw, 0) * max(ih, 0) / area if area > 0 else 0.0


def boxes_overlap(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    """Do two inclusive boxes share at least one pixel (or, for real-valued boxes, a point)?"""
    return min(a[2], b[2]) >= max(a[0], b[0]) and min(a[3], b[3]) >= max(a[1], b[1])


def border_band(scale: int) -> int:
    """The image-border band b of the track rules (working px): 2 full-resolution px at working scale ``scale``
    (full px per working px), at least 1."""
    return max(1, int(round(2.0 / scale)))


def touches_border(box: tuple[int, int, int, int], size: tuple[int, int], band: int) -> bool:
    """Does inclusive box ``box`` come within ``band`` px of the border of an image of ``size`` (w, h)?"""
    w, h = size
    return box[0] < band or box[1] < band or box[2] > w - 1 - band or box[3] > h - 1 - band
