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

import numpy as np

from tracker.filter.blob_follow import footprint
from tracker.filter.colour_input import box_surface_depth
from tracker.geometry.box_renderer import pixel_rays

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
    silhouette pixel on the image."""
    if trk.meshes[obj] is not None:
        return None
    fp = footprint(trk, obj)
    if fp is None:
        return None
    h, w = depth.shape[:2]
    u0, v0 = max(int(np.floor(fp[0])), 0), max(int(np.floor(fp[1])), 0)
    u1, v1 = min(int(np.ceil(fp[2])) + 1, w), min(int(np.ceil(fp[3])) + 1, h)
    if u1 <= u0 or v1 <= v0:
        return None
    vv, uu = np.mgrid[v0:v1:stride, u0:u1:stride]
    uu, vv = uu.ravel(), vv.ravel()
    surface = box_surface_depth(trk, obj, uu, vv)
    on = np.isfinite(surface)
    if not on.any():
        return None
    uu, vv, surface = uu[on], vv[on], surface[on]
    z = np.asarray(depth[vv, uu], np.float64)
    valid = np.isfinite(z) & (z > 0)
    diff = np.where(valid, z - surface, 0.0)
    nearer = valid & (diff < -SURFACE_TOLERANCE_M)
    shown = valid & (np.abs(diff) <= SURFACE_TOLERANCE_M)
    behind = valid & (diff > SURFACE_TOLERANCE_M)
    table = np.zeros_like(behind)
    if plane is not None and behind.any():
        normal, offset = np.asarray(plane[0], np.float64), float(plane[1])
        pts = pixel_rays(trk.intrinsics, uu[behind].astype(np.float64), vv[behind].astype(np.float64))
        pts = pts * z[behind][:, None]
        table[behind] = np.abs(pts @ normal + offset) <= TABLE_TOLERANCE_M
    n = int(len(z))
    return FootprintDepth(n, float(1.0 - valid.mean()), float(nearer.mean()), float(shown.mean()),
                          float(behind.mean()), float(table.mean()))


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
