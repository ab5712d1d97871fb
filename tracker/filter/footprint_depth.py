"""What this frame's depth shows over a hidden part's footprint (not in the seed; an addition of the hand carry).

A resting part that a hand hides has, over its projected silhouette, depth nearer than its own surface (the hand
over it: *covered*); it may still be resting, and the rest prior holds it. A part that a hand has picked up has
left its place: over the silhouette of its last estimate the depth camera now sees the table top behind where its
surface was (*left*), even while the hand and the lifted part still cover the rest of it. The carry's motion test
cannot see this for a part the rest prior holds (its estimate does not move), so with ``carry_left_table`` the
hidden-parts stage starts the carry at once, from the hand's motion, on the first frame whose depth shows the table
over that fraction of the footprint (:func:`left_place`).

Camera frame, metres; pixels are full-resolution image coordinates (centres at integers). Box parts only: a mesh part
has no classification (None).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from tracker.geometry.box_renderer import box_depths, pixel_rays
from tracker.geometry.fma import rigid_point

SURFACE_TOLERANCE_M = 0.01
"""Depth within this distance (m) of the estimate's rendered surface shows the part; nearer is in front of it,
farther is behind it."""

TABLE_TOLERANCE_M = 0.01
"""A point behind the part's surface within this distance (m) of the table plane is the table top."""


@dataclass(frozen=True)
class FootprintDepth:
    """Fractions of the sampled silhouette pixels (``n`` of them) of a part's estimate by what the depth shows there:
    no measurement (``missing``), nearer than the surface (``nearer``: a hand or another part in front), the surface
    itself (``shown``), behind it (``behind``) and, among those behind, the table plane (``table``). ``nearer``,
    ``shown`` and ``behind`` add up to the valid fraction ``1 - missing``."""

    n: int
    missing: float
    nearer: float
    shown: float
    behind: float
    table: float

    @property
    def valid(self) -> float:
        """Fraction of the sampled pixels with a depth measurement."""
        return 1.0 - self.missing

    def of_valid(self, fraction: float) -> float:
        """``fraction`` (of all sampled pixels) as a fraction of those with depth (0 when none has depth)."""
        return fraction / self.valid if self.valid > 0 else 0.0


def classify_footprint(trk, obj: int, depth: np.ndarray, plane, stride: int = 2) -> FootprintDepth | None:
    """Classify the depth over box part ``obj``'s silhouette at its estimate (every ``stride``-th pixel of its
    projected rectangle; ``depth`` in metres, NaN or 0 = no measurement; ``plane`` = the table's ``(normal, offset)``
    with the normal up, or None: nothing then counts as table). None for a mesh part or an estimate with no
    silhouette pixel on the image. The counts in one compiled call (:func:`_footprint_counts`), the table test on
    the pixels behind the surface in numpy: the values of the numpy form (``footprint``, ``box_surface_depth`` and
    the masks' means)."""
    if trk.meshes[obj] is not None:
        return None
    est = trk.estimates[trk.names[obj]]
    intr = trk.intrinsics
    n, n_valid, n_nearer, n_shown, n_behind, bu, bv, bz = _footprint_counts(
        np.ascontiguousarray(trk.corners[obj], np.float64), np.ascontiguousarray(est.R, np.float64), est.t,
        np.ascontiguousarray(trk.center[obj], np.float64), np.ascontiguousarray(trk.half[obj], np.float64),
        float(intr.fx), float(intr.fy), float(intr.cx), float(intr.cy), depth, int(stride))
    if n == 0:
        return None
    n_table = 0
    if plane is not None and n_behind > 0:
        normal, offset = np.asarray(plane[0], np.float64), float(plane[1])
        pts = pixel_rays(intr, bu, bv)
        pts = pts * bz[:, None]
        n_table = int(np.count_nonzero(np.abs(pts @ normal + offset) <= TABLE_TOLERANCE_M))
    return FootprintDepth(n, float(1.0 - n_valid / n), n_nearer / n, n_shown / n, n_behind / n, n_table / n)


@nb.njit(cache=True)
def footprint_bounds(corners, R, t, fx, fy, cx, cy):
    """``(ok, u_min, v_min, u_max, v_max)``: :func:`tracker.filter.blob_follow.footprint` of the box corners
    ``corners`` (8, 3, body frame) at ``(R, t)`` (``corners @ R.T + t`` with the fused multiply-adds of numpy's
    BLAS product of these shapes, :mod:`tracker.geometry.fma`; ``fx · x / z + cx``); ``ok`` False when a corner lies
    closer than 5 cm to the camera plane."""
    umin, vmin, umax, vmax = np.inf, np.inf, -np.inf, -np.inf
    for i in range(corners.shape[0]):
        x, y, z = rigid_point(R, t, corners[i, 0], corners[i, 1], corners[i, 2])
        if z < 0.05:
            return False, 0.0, 0.0, 0.0, 0.0
        u = fx * x / z + cx
        v = fy * y / z + cy
        umin, umax = min(umin, u), max(umax, u)
        vmin, vmax = min(vmin, v), max(vmax, v)
    return True, umin, vmin, umax, vmax


@nb.njit(cache=True)
def footprint_rect(corners, R, t, fx, fy, cx, cy, h, w):
    """``(ok, u0, v0, u1, v1)``: the pixel rectangle (end-exclusive, clipped to an ``h`` × ``w`` image; may be empty)
    of :func:`footprint_bounds`, as :func:`tracker.filter.hidden_parts.estimate_rect` forms it; ``ok`` False as
    there."""
    ok, fu0, fv0, fu1, fv1 = footprint_bounds(corners, R, t, fx, fy, cx, cy)
    if not ok:
        return False, 0, 0, 0, 0
    return (True, max(int(np.floor(fu0)), 0), max(int(np.floor(fv0)), 0), min(int(np.ceil(fu1)) + 1, w),
            min(int(np.ceil(fv1)) + 1, h))


@nb.njit(cache=True)
def _footprint_counts(corners, R, t, center, half, fx, fy, cx, cy, depth, stride):
    """:func:`classify_footprint`'s pixel work: the silhouette pixels sampled (``n``; 0 = none, or no footprint), how
    many have depth, are nearer than the surface, show it, lie behind it, and the behind ones' pixels and depths
    (float64, for the table test)."""
    empty = np.empty(0)
    ok, u0, v0, u1, v1 = footprint_rect(corners, R, t, fx, fy, cx, cy, depth.shape[0], depth.shape[1])
    if not ok or u1 <= u0 or v1 <= v0:
        return 0, 0, 0, 0, 0, empty, empty, empty
    nu = (u1 - u0 + stride - 1) // stride
    nv = (v1 - v0 + stride - 1) // stride
    pu = np.empty(nu * nv)
    pv = np.empty(nu * nv)
    m = 0
    for v in range(v0, v1, stride):  # np.mgrid's order, raveled
        for u in range(u0, u1, stride):
            pu[m] = u
            pv[m] = v
            m += 1
    surface = box_depths(R, t, center, half, pu, pv, fx, fy, cx, cy)
    n = n_valid = n_nearer = n_shown = n_behind = 0
    bu = np.empty(m)
    bv = np.empty(m)
    bz = np.empty(m)
    for i in range(m):
        s = surface[i]
        if not np.isfinite(s):
            continue
        n += 1
        z = np.float64(depth[int(pv[i]), int(pu[i])])
        if not (np.isfinite(z) and z > 0):
            continue
        n_valid += 1
        diff = z - s
        if diff < -SURFACE_TOLERANCE_M:
            n_nearer += 1
        if abs(diff) <= SURFACE_TOLERANCE_M:
            n_shown += 1
        if diff > SURFACE_TOLERANCE_M:
            bu[n_behind] = pu[i]
            bv[n_behind] = pv[i]
            bz[n_behind] = z
            n_behind += 1
    return n, n_valid, n_nearer, n_shown, n_behind, bu[:n_behind], bv[:n_behind], bz[:n_behind]


def left_place(fp: FootprintDepth | None, min_table: float, min_valid: float = 0.25) -> bool:
    """Has the part left the place of its estimate (``carry_left_table``)? The depth shows the table top on at least
    ``min_table`` of the silhouette's pixels with depth, more of them than show the part's surface, and at least
    ``min_valid`` of the pixels have depth (a hand's projector shadow leaves many without)."""
    if fp is None or min_table <= 0 or fp.valid < min_valid:
        return False
    table = fp.of_valid(fp.table)
    return table >= min_table and fp.table > fp.shown


def covered(fp: FootprintDepth | None, min_nearer: float = 0.5) -> bool:
    """Is the part covered: something nearer than its surface on at least ``min_nearer`` of the silhouette's pixels
    with depth, and no table showing where it is? (A hand over a part that may still be resting.)"""
    if fp is None or fp.valid <= 0:
        return False
    return fp.of_valid(fp.nearer) >= min_nearer and fp.table == 0.0
