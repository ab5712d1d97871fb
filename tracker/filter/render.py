"""Rendering stage: which pixels are evaluated this frame, and the depth of every particle's parts there.

Boxes are ray-cast exactly (:mod:`tracker.geometry.box_renderer`), meshes rasterised
(:mod:`tracker.geometry.mesh_renderer`), into the per-particle depth columns of the evaluated pixels of the
downsampled grid (full-resolution pixel coordinates, camera frame, metres).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numba as nb
import numpy as np

from tracker.geometry.box_renderer import render_boxes_at_pixels
from tracker.geometry.mesh_renderer import render_mesh_at_pixels

if TYPE_CHECKING:
    from tracker.filter.particle_filter import MultiObjectTracker


def render(trk: MultiObjectTracker, obj, p, R, particles, rays, pu, pv, gi, gj, subset, D, loc, dirty) -> None:
    """Depth of part ``obj`` for the listed ``particles`` at the evaluated pixels ``subset`` into ``D``."""
    if particles.size == 0 or subset.size == 0:
        return
    intr = trk.intrinsics
    mesh = trk.meshes[obj]
    if mesh is None:
        render_boxes_at_pixels(R, p, trk.center, trk.half, obj, particles, rays, pu, pv, subset,
                               intr.fx, intr.fy, intr.cx, intr.cy, D, loc, dirty)
    else:
        render_mesh_at_pixels(R, p, mesh.vertices, mesh.faces, obj, particles, gi, gj, subset,
                              float(trk.config.downsample), float(trk._off), intr.fx, intr.fy, intr.cx,
                              intr.cy, D, loc, dirty, int(trk._lattice[obj]))


def bbox(trk, obj, p, R) -> tuple[float, float, float, float]:
    """Full-resolution pixel rectangle (umin, umax, vmin, vmax) covering part ``obj`` for all given poses
    (positions ``p`` (N, 3), rotations ``R`` (N, 3, 3)), widened by 1 px; unbounded when a corner lies within 1 cm
    of the camera plane, empty (inf, −inf, …) without poses."""
    if p.shape[0] == 0:
        return (np.inf, -np.inf, np.inf, -np.inf)
    intr = trk.intrinsics
    return _projected_bounds(R, p, trk.corners[obj], intr.fx, intr.fy, intr.cx, intr.cy)


@nb.njit(cache=True)
def _projected_bounds(R, p, corners, fx, fy, cx, cy):
    umin, umax, vmin, vmax = np.inf, -np.inf, np.inf, -np.inf
    for n in range(p.shape[0]):
        for c in range(corners.shape[0]):
            x = R[n, 0, 0] * corners[c, 0] + R[n, 0, 1] * corners[c, 1] + R[n, 0, 2] * corners[c, 2] + p[n, 0]
            y = R[n, 1, 0] * corners[c, 0] + R[n, 1, 1] * corners[c, 1] + R[n, 1, 2] * corners[c, 2] + p[n, 1]
            z = R[n, 2, 0] * corners[c, 0] + R[n, 2, 1] * corners[c, 1] + R[n, 2, 2] * corners[c, 2] + p[n, 2]
            if z < 0.01:
                return (-np.inf, np.inf, -np.inf, np.inf)
            u = fx * x / z + cx
            v = fy * y / z + cy
            umin = min(umin, u)
            umax = max(umax, u)
            vmin = min(vmin, v)
            vmax = max(vmax, v)
    return (umin - 1.0, umax + 1.0, vmin - 1.0, vmax + 1.0)


def evaluated_pixels(trk, depth, p_prev, R_prev, p_det, R_det):
    """Valid pixels near the parts: (indices into the downsampled grid (P,), per-part region masks (K, P)),
    or None when there are none. A part's region is its projected rectangle over all particles (previous and
    predicted poses) widened by the margin and the motion-noise spread (the mixture's std, 3σ)."""
    if depth is None:
        return None
    cfg = trk.config
    intr = trk.intrinsics
    z = depth[np.ix_(trk._vs, trk._us)].reshape(-1)
    valid = np.isfinite(z) & (z > 0) & (z < cfg.max_depth)
    if not valid.any():
        return None
    k = len(trk.parts)
    regions = np.zeros((k, z.size), bool)
    f = cfg.wide_noise_fraction
    spread = np.sqrt((1.0 - f) + f * cfg.wide_noise_scale**2)
    for i in range(k):
        rect = union(bbox(trk, i, p_prev[:, i], R_prev[:, i]), bbox(trk, i, p_det[:, i], R_det[:, i]))
        zc = max(float(np.median(p_det[:, i, 2])), 0.05)
        radius = float(np.linalg.norm(trk.half[i]) + np.linalg.norm(trk.center[i]))
        scale = spread * trk._noise_scale[i]
        margin = (cfg.roi_margin_px * cfg.downsample
                  + 3.0 * scale * (cfg.sigma_v + cfg.sigma_w * radius) * intr.fx / zc)
        regions[i] = ((trk._pu >= rect[0] - margin) & (trk._pu <= rect[1] + margin)
                      & (trk._pv >= rect[2] - margin) & (trk._pv <= rect[3] + margin))
    budget = cfg.likelihood_pixels_per_part
    if budget > 0:
        # a part that covers many grid pixels (a large mesh, a part close to the camera) is evaluated on an even
        # subset of at most ``budget`` of them: the likelihood's cost stays bounded, the refinement after the
        # filter restores the precision
        # subset is a coarser lattice of the grid (every c-th pixel in each axis), so that a mesh part can be
        # rasterised on that lattice only
        keep = np.zeros(z.size, bool)
        for i in range(k):
            sel = regions[i] & valid
            count = int(np.count_nonzero(sel))
            c = max(int(np.ceil(np.sqrt(count / budget))), 1) if count > budget else 1
            if c > 1:
                sel &= (trk._gi % c == 0) & (trk._gj % c == 0)
            trk._lattice[i] = c
            keep |= sel
    else:
        keep = regions.any(axis=0) & valid
    pix = np.nonzero(keep)[0].astype(np.int64)
    if not pix.size:
        return None
    return pix, regions[:, pix]


def union(a, b):
    """Smallest pixel rectangle (umin, umax, vmin, vmax) holding both."""
    return (min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3]))
