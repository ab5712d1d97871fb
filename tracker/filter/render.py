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
    k = len(trk.parts)
    f = cfg.wide_noise_fraction
    spread = np.sqrt((1.0 - f) + f * cfg.wide_noise_scale**2)
    bounds = _region_bounds(p_prev, R_prev, p_det, R_det, trk._roi_corners, trk._roi_radii,
                            np.asarray(trk._noise_scale, np.float64), float(spread),
                            float(cfg.roi_margin_px * cfg.downsample), float(cfg.sigma_v), float(cfg.sigma_w),
                            intr.fx, intr.fy, intr.cx, intr.cy)
    # a part that covers many grid pixels (a large mesh, a part close to the camera) is evaluated on an even subset
    # of at most ``likelihood_pixels_per_part`` of them (0: all): the likelihood's cost stays bounded, the refinement
    # after the filter restores the precision; the subset is a coarser lattice of the grid (every c-th pixel in each
    # axis), so that a mesh part can be rasterised on that lattice only
    # a quiet part (its pass skipped this frame, filter/quiet_parts.py) gets the smaller budget
    # ``quiet_pixels_per_part``: it is evaluated only at its prediction, for the weights and its visible fraction
    depth = np.asarray(depth)
    max_depth = depth.dtype.type(cfg.max_depth) if depth.dtype.kind == "f" else float(cfg.max_depth)
    budgets = np.full(k, int(cfg.likelihood_pixels_per_part), np.int64)
    # (``quiet_thin``: a quiet part whose pass runs gets it too, its likelihood taken on fewer pixels)
    quiet = getattr(trk, "_quiet_now", None)
    if quiet is not None and cfg.quiet_pixels_per_part > 0 and budgets[0] > 0:
        thin = np.asarray(quiet, bool)
        if cfg.quiet_thin:
            thin = thin | np.asarray(trk._settled, bool)
        budgets[thin] = min(int(cfg.quiet_pixels_per_part), int(budgets[0]))
    pix, regions, any_valid = _evaluated(depth, trk._vs, trk._us, max_depth, trk._pu, trk._pv, trk._gi, trk._gj,
                                         bounds, budgets, trk._lattice)
    if not any_valid or not pix.size:
        return None
    return pix, regions


@nb.njit(cache=True)
def _region_bounds(p_prev, R_prev, p_det, R_det, corners, radii, noise_scale, spread, margin_px, sigma_v, sigma_w,
                   fx, fy, cx, cy):
    """Per part (K, 4) the rectangle ``(umin, umax, vmin, vmax)`` of :func:`evaluated_pixels`: the union of
    :func:`bbox` at the previous (``p_prev`` (N, K, 3), ``R_prev`` (N, K, 3, 3)) and the predicted poses, widened
    by ``margin_px`` plus 3σ of the motion noise at the predicted positions' median depth (the operations of the
    Python form, same values; ``corners`` (K, 8, 3) body frame, ``radii`` (K,) metres)."""
    k = corners.shape[0]
    out = np.empty((k, 4))
    for i in range(k):
        if p_prev.shape[0] == 0:
            a = (np.inf, -np.inf, np.inf, -np.inf)
            b = a
        else:
            a = _projected_bounds(R_prev[:, i], p_prev[:, i], corners[i], fx, fy, cx, cy)
            b = _projected_bounds(R_det[:, i], p_det[:, i], corners[i], fx, fy, cx, cy)
        # union as Python's min / max take it (the first argument unless the second is strictly beyond it)
        u0 = b[0] if b[0] < a[0] else a[0]
        u1 = b[1] if b[1] > a[1] else a[1]
        v0 = b[2] if b[2] < a[2] else a[2]
        v1 = b[3] if b[3] > a[3] else a[3]
        med = np.median(p_det[:, i, 2])
        zc = 0.05 if 0.05 > med else med
        scale = spread * noise_scale[i]
        margin = margin_px + 3.0 * scale * (sigma_v + sigma_w * radii[i]) * fx / zc
        out[i, 0] = u0 - margin
        out[i, 1] = u1 + margin
        out[i, 2] = v0 - margin
        out[i, 3] = v1 + margin
    return out


@nb.njit(cache=True)
def _evaluated(depth, vs, us, max_depth, pu, pv, gi, gj, bounds, budgets, lattice):
    """The evaluated grid pixels (P,), the parts' region masks at them (K, P) and whether any grid pixel has valid
    depth (finite, > 0, < ``max_depth``; when none, nothing else is done). A pixel is evaluated when its depth is
    valid and it lies in a part's rectangle ``bounds[k] = (umin, umax, vmin, vmax)`` (inclusive), on the part's
    lattice ``lattice[k]``: every c-th grid pixel in each axis, c the smallest with at most ``budgets[k]`` of its
    valid region pixels left (``budgets[k]`` 0: all pixels, ``lattice[k]`` not written).

    The grid is row-major (pixel g = row ``gj[g]``, column ``gi[g]``, full-resolution ``(pu[g], pv[g])`` =
    ``(us[gi], vs[gj])``), so a rectangle holds the grid pixels of a range of columns and a range of rows: each part
    visits only those, and the depth is read only where a rectangle needs it (and until the first valid pixel, for
    the test of the whole grid)."""
    nu = us.shape[0]
    nv = vs.shape[0]
    ng = pu.shape[0]
    k = bounds.shape[0]
    valid = np.full(ng, -1, np.int8)  # -1: not read yet
    any_valid = False
    for g in range(ng):
        valid[g] = _valid_depth(depth, vs, us, g, nu, max_depth)
        if valid[g]:
            any_valid = True
            break
    if not any_valid:
        return np.empty(0, np.int64), np.empty((k, 0), np.bool_), False
    inside = np.zeros((k, ng), np.bool_)
    keep = np.zeros(ng, np.bool_)
    cols = np.empty(nu, np.int64)
    rows = np.empty(nv, np.int64)
    for i in range(k):
        budget = budgets[i]
        umin, umax, vmin, vmax = bounds[i, 0], bounds[i, 1], bounds[i, 2], bounds[i, 3]
        n_cols = 0
        for c in range(nu):  # the first grid row holds every column's u
            if pu[c] >= umin and pu[c] <= umax:
                cols[n_cols] = c
                n_cols += 1
        n_rows = 0
        for r in range(nv):
            if pv[r * nu] >= vmin and pv[r * nu] <= vmax:
                rows[n_rows] = r
                n_rows += 1
        count = 0
        for rr in range(n_rows):
            for cc in range(n_cols):
                g = rows[rr] * nu + cols[cc]
                inside[i, g] = True
                if valid[g] < 0:
                    valid[g] = _valid_depth(depth, vs, us, g, nu, max_depth)
                if valid[g]:
                    count += 1
        c = 1
        if budget > 0:
            if count > budget:
                c = max(int(np.ceil(np.sqrt(count / budget))), 1)
            lattice[i] = c
        for rr in range(n_rows):
            for cc in range(n_cols):
                g = rows[rr] * nu + cols[cc]
                if valid[g] and (budget <= 0 or c == 1 or (gi[g] % c == 0 and gj[g] % c == 0)):
                    keep[g] = True
    n = 0
    for g in range(ng):
        n += keep[g]
    pix = np.empty(n, np.int64)
    regions = np.empty((k, n), np.bool_)
    m = 0
    for g in range(ng):
        if keep[g]:
            pix[m] = g
            for i in range(k):
                regions[i, m] = inside[i, g]
            m += 1
    return pix, regions, any_valid


@nb.njit(cache=True, inline="always")
def _valid_depth(depth, vs, us, g, nu, max_depth):
    """1 when grid pixel ``g``'s depth is finite, > 0 and < ``max_depth``, else 0."""
    z = depth[vs[g // nu], us[g % nu]]
    return 1 if (np.isfinite(z) and z > 0 and z < max_depth) else 0


def union(a, b):
    """Smallest pixel rectangle (umin, umax, vmin, vmax) holding both."""
    return (min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3]))
