"""Each hand at the far end of its own arm (product addition, ``HandTrackerConfig.arm_anchor``).

Two hands that touch or lie on each other form one skin region in which neither colour nor flow tells them apart,
and the two particle filters then split it side by side or both sit on one hand. But each hand is the far end of an
arm that enters the image from its border, and the two arms seldom swap where they enter. This module finds, per
frame and without tracking, each arm and the skin pixels at its end:

1. Foreground: the pixels nearer the camera than the session's first (hand-free) depth frame by :data:`FG_GAP`, or
   without depth where that frame had depth (an arm too near the sensor); opened with a 3×3 square. More than
   :data:`MAX_FG_FRAC` of the frame in front of the background: the camera has moved (or the first frame held a
   hand), and nothing is found.
2. Arms: the 8-connected components of the foreground without the (dilated) skin mask — the sleeves — of at least
   :data:`MIN_ARM_FRAC` of the image that touch the image border in one run (two runs: two arms crossing in one
   component; no answer there). The entry point is the mean of its border pixels.
3. Wrist: the sleeve pixels whose straight-line distance from the arm's entry point is at least :data:`WRIST_FAR`
   of the farthest and that lie next to skin; the skin pixels next to them seed the hand.
4. Hands: one multi-source geodesic distance over the skin mask from all arms' seeds at once (Dijkstra, 4-neighbour
   steps of cost 1, plus :data:`DEPTH_STEP_COST` across a depth step larger than :data:`DEPTH_STEP` m: the edge of
   the upper hand over the lower one); each skin pixel belongs to the arm whose wrist reaches it first. A hand's box
   is the tight box of its pixels (at least :data:`MIN_HAND_PX`).

Without depth nothing is found. Dev measurement (``hands-s2`` tuning seeds 0–4, this detector alone, no tracking,
the left entry taken as one hand): per hand-frame F̄^b 0.76 / 0.85 / 0.66 / 0.83 / 0.55; used where it finds the
track's arm, the tracker's box otherwise, 0.714 → 0.814 over filter seeds 0–3 (every run but one better). In the
tracker (:meth:`tracker.hands.tracker.HandTracker._report_arms`) see its module docstring. Not handled: two arms
that cross in one sleeve component (a nearest-axis split of the X, tried, gave the far ends to the wrong arms),
arms of the same colour as skin (bare forearms: no sleeve, nothing found), a moving camera (the first frame's
depth is the background).

Images are at the tracker's working resolution; boxes inclusive working px [u0, v0, u1, v1]; depth in metres.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import cv2
import numba as nb
import numpy as np

FG_GAP = 0.02
"""Metres a pixel must lie nearer the camera than the background depth to be foreground (arm, hand)."""
MAX_FG_FRAC = 0.5
"""Largest foreground share (of the pixels with background depth) for which the background frame is trusted."""
MIN_ARM_FRAC = 300 / (320 * 240)
"""Smallest sleeve component, as a share of the working image, that counts as an arm."""
BORDER_PX = 2
"""Working px from the image edge within which a sleeve pixel is an entry pixel."""
RUN_GAP = 8.0
"""Gap (working px along the image border) that splits a component's border pixels into separate runs."""
MIN_RUN = 6
"""Fewest border pixels of a run."""
WRIST_FAR = 0.7
"""Share of the farthest distance from the arm's entry point beyond which a sleeve pixel next to skin is wrist."""
DEPTH_STEP = 0.012
"""Depth difference (m) between 4-neighbours that counts as a step (the edge of the upper hand)."""
DEPTH_STEP_COST = 20.0
"""Extra geodesic cost (working px) of crossing a depth step."""
MIN_HAND_PX = 20
"""Fewest skin pixels (working px) a hand must get to be reported."""


@dataclass
class ArmHand:
    """One arm's hand: ``entry`` (x, y) the mean of the arm's border pixels, ``box`` the inclusive box of its skin
    pixels, ``n`` their count (working px)."""

    entry: tuple[float, float]
    box: tuple[int, int, int, int]
    n: int


@nb.njit(cache=True, nogil=True)
def geodesic_labels(mask, z, seeds, step, step_cost):
    """Multi-source geodesic labelling over ``mask`` (uint8 H×W) from ``seeds`` (int32 H×W, 0 = none, k > 0 the
    label; only seeds on the mask count): Dijkstra with 4-neighbour steps of cost 1 plus ``step_cost`` where both
    depths ``z`` (float64 H×W, ≤ 0 unknown) are known and differ by more than ``step``. Returns (labels int32,
    distances float64; 1e18 where not reached)."""
    h, w = mask.shape
    dist = np.full((h, w), 1e18)
    lab = np.zeros((h, w), np.int32)
    heap = [(0.0, 0, 0)]
    heap.pop()
    for y in range(h):
        for x in range(w):
            if seeds[y, x] > 0 and mask[y, x]:
                dist[y, x] = 0.0
                lab[y, x] = seeds[y, x]
                heap.append((0.0, y, x))
    heapq.heapify(heap)
    dys = (1, -1, 0, 0)
    dxs = (0, 0, 1, -1)
    while len(heap):
        d, y, x = heapq.heappop(heap)
        if d > dist[y, x]:
            continue
        for q in range(4):
            yy = y + dys[q]
            xx = x + dxs[q]
            if yy < 0 or xx < 0 or yy >= h or xx >= w or not mask[yy, xx]:
                continue
            c = 1.0
            za = z[y, x]
            zb = z[yy, xx]
            if za > 0 and zb > 0 and abs(za - zb) > step:
                c += step_cost
            nd = d + c
            if nd < dist[yy, xx]:
                dist[yy, xx] = nd
                lab[yy, xx] = lab[y, x]
                heapq.heappush(heap, (nd, yy, xx))
    return lab, dist


def working_depth(depth: np.ndarray, scale: int, shape: tuple[int, int]) -> np.ndarray:
    """Full-resolution depth (m) subsampled every ``scale``-th px to the working ``shape`` (H, W); unknown → 0."""
    z = np.asarray(depth, np.float64)[::scale, ::scale][: shape[0], : shape[1]]
    z = np.where(np.isfinite(z) & (z > 0), z, 0.0)
    if z.shape != shape:
        out = np.zeros(shape)
        out[: z.shape[0], : z.shape[1]] = z
        z = out
    return z


def foreground(z: np.ndarray, background: np.ndarray) -> np.ndarray:
    """Bool mask of the pixels nearer than ``background`` by FG_GAP, or without depth where the background has it."""
    bg_ok = background > 0
    fg = bg_ok & (((z > 0) & (z < background - FG_GAP)) | (z <= 0))
    return cv2.morphologyEx(fg.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)).astype(bool)


def _border_runs(ys: np.ndarray, xs: np.ndarray, h: int, w: int) -> list[np.ndarray]:
    """Indices of border pixels grouped into runs along the image border (clockwise perimeter coordinate)."""
    b = BORDER_PX
    bottom_left = np.where(ys >= h - b, w + h + (w - xs), 2 * w + h + (h - ys))
    p = np.where(ys < b, xs, np.where(xs >= w - b, w + ys, bottom_left)).astype(np.float64)
    order = np.argsort(p)
    runs = np.split(order, np.nonzero(np.diff(p[order]) > RUN_GAP)[0] + 1)
    if len(runs) > 1 and p[order[0]] + 2 * (w + h) - p[order[-1]] <= RUN_GAP:  # a run through the top-left corner
        runs = [np.concatenate([runs[-1], runs[0]])] + runs[1:-1]
    return [r for r in runs if len(r) >= MIN_RUN]


def arm_hands(skin: np.ndarray, z: np.ndarray, background: np.ndarray) -> list[ArmHand]:
    """The hands at the ends of the arms of one frame (module docstring). ``skin``: the colour mask (uint8 0/1,
    working H×W); ``z``, ``background``: this frame's and the first frame's depth at the working resolution (m, 0 =
    unknown)."""
    h, w = skin.shape
    sk = cv2.morphologyEx(np.ascontiguousarray(skin, np.uint8), cv2.MORPH_OPEN,
                          cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3)))  # fmt: skip
    if not sk.any():
        return []
    fg = foreground(z, background)
    if np.count_nonzero(fg) > MAX_FG_FRAC * max(np.count_nonzero(background > 0), 1):
        return []  # the background frame no longer fits (the camera moved, or a hand was in the first frame)
    sleeve = (fg & ~cv2.dilate(sk, np.ones((3, 3), np.uint8)).astype(bool)).astype(np.uint8)
    sleeve = cv2.morphologyEx(sleeve, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(sleeve, connectivity=8)
    b = BORDER_PX
    near_skin = cv2.dilate(sk, np.ones((5, 5), np.uint8)).astype(bool)
    seeds = np.zeros((h, w), np.int32)
    entries: list[tuple[float, float]] = []
    for i in range(1, n):
        if stats[i, cv2.CC_STAT_AREA] < MIN_ARM_FRAC * h * w:
            continue
        x0, y0, bw, bh = (int(v) for v in stats[i, :4])
        if not (x0 < b or y0 < b or x0 + bw > w - b or y0 + bh > h - b):
            continue
        m = lab[y0 : y0 + bh, x0 : x0 + bw] == i
        border = np.zeros_like(m)
        border[: max(b - y0, 0)] = True
        border[max(h - b - y0, 0) :] = True
        border[:, : max(b - x0, 0)] = True
        border[:, max(w - b - x0, 0) :] = True
        bys, bxs = np.nonzero(m & border)
        if len(bys) == 0:
            continue
        runs = _border_runs(bys + y0, bxs + x0, h, w)
        if len(runs) != 1:
            continue  # no border run long enough, or two arms crossing in one component
        ex, ey = float(bxs.mean()), float(bys.mean())
        gy, gx = np.mgrid[0:bh, 0:bw]
        dist = np.hypot(gx - ex, gy - ey)
        dmax = float(dist[m].max())
        wrist = m & (dist >= WRIST_FAR * dmax) & near_skin[y0 : y0 + bh, x0 : x0 + bw]
        if not wrist.any():
            continue
        full = np.zeros((h, w), np.uint8)
        full[y0 : y0 + bh, x0 : x0 + bw] = wrist
        seed_px = sk.astype(bool) & cv2.dilate(full, np.ones((5, 5), np.uint8)).astype(bool)
        if not seed_px.any():
            continue
        entries.append((ex + x0, ey + y0))
        seeds[seed_px & (seeds == 0)] = len(entries)
    if not entries:
        return []
    labels, _ = geodesic_labels(sk, z, seeds, DEPTH_STEP, DEPTH_STEP_COST)
    out = []
    for k, e in enumerate(entries):
        ys, xs = np.nonzero(labels == k + 1)
        if len(xs) >= MIN_HAND_PX:
            out.append(ArmHand(e, (int(xs.min()), int(ys.min()), int(xs.max()), int(ys.max())), len(xs)))
    return out
