"""Colour input stage (spec 4.11): each part's control input from its colour detection, re-seeding of parts whose
reliable colour blob lies off their estimate, and the blob masks the likelihood, re-seeding and refinement use.

Pixels are full-resolution image coordinates; poses camera frame, metres.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numba as nb
import numpy as np

from tracker.filter import render
from tracker.filter.motion_model import color_input
from tracker.geometry.box_renderer import _slab_depth, box_depths, pixel_rays, render_boxes_at_pixels
from tracker.geometry.fma import rigid_point
from tracker.geometry.pose import Pose

if TYPE_CHECKING:
    from tracker.filter.frame_context import FrameContext
    from tracker.filter.particle_filter import MultiObjectTracker


def control_inputs(trk: MultiObjectTracker, ctx: FrameContext, detections) -> tuple[np.ndarray, np.ndarray]:
    """The colour control input u (K, 3) of every part and which parts have a reliable blob (K,) bool."""
    cfg = trk.config
    intr = trk.intrinsics
    depth = ctx.depth
    k = len(trk.parts)
    u = np.zeros((k, 3))
    trk._color_targets = []  # (part index, (u, v), weight) for the optional colour likelihood term
    detected = np.zeros(k, bool)
    trk._blob_off = np.zeros(k, bool)  # reliable blob off the estimate's silhouette (re-acquisition looks at it)
    trk._pre_reseed = {}  # part index -> its estimate before this frame's re-seed at its blob (the hand carry's)
    trk._pre_reseed_p = {}  # part index -> its particles' positions (N, 3) before that re-seed (carry_sliver_particles)
    if cfg.use_color_input and detections:
        for i, name in enumerate(trk.names):
            det = detections.get(name)
            if det is None:
                continue
            score = float(getattr(det, "score", 0.0) or 0.0)
            center = getattr(det, "center", None)
            if center is None or score < cfg.min_detection_score:
                continue
            area = getattr(det, "area", None)
            ratio = None  # area_ratio(trk, i, area), computed when first needed (the estimate does not move before)
            if confident(trk, score, area):
                ratio = area_ratio(trk, i, area)
            reliable = ratio is not None and ratio >= cfg.reseed_min_area_ratio
            if ratio is not None and not reliable and far_sliver(trk, i, score, area, center):
                reliable = True  # a sliver far from the estimate: biased centroid, but far nearer than the estimate
            detected[i] = reliable
            hit = surface_depth(trk, i, center)
            off_silhouette = reliable and not np.isfinite(hit)
            trk._blob_off[i] = off_silhouette
            if cfg.color_area_weighting and not off_silhouette:
                score *= area_ratio(trk, i, area) if ratio is None else ratio
            if off_silhouette and cfg.reseed_fraction > 0 and depth is not None:
                trk._pre_reseed[i] = trk.estimates[name]
                trk._pre_reseed_p[i] = trk.p[:, i].copy()
                reseed(trk, i, det, depth)
                hit = surface_depth(trk, i, center)
            if cfg.color_likelihood_px > 0:
                # with a dead zone the term tolerates the centroid bias of a partly hidden blob: full score
                wgt = min(float(det.score) if cfg.color_term_dead_zone > 0 else score, 1.0)
                trk._color_targets.append((i, np.asarray(center, np.float64), wgt))
            est = trk.estimates[name]
            offset = float(est.t[2] - hit) if np.isfinite(hit) else surface_fallback(trk, i)
            blob = blob_mask(trk, det, depth.shape) if depth is not None and cfg.color_mask_likelihood else None
            bias = None
            if cfg.color_visible_centroid and depth is not None and not off_silhouette:
                bias = visible_centroid_bias(trk, i, depth)
            u[i] = color_input(center, min(score, 1.0), est, depth, intr, cfg.lambda_z, cfg.depth_radius_px,
                               offset, mask=blob, bias_px=bias)
    return u, detected


def visible_centroid_bias(trk, obj: int, depth: np.ndarray, stride: int = 2) -> np.ndarray | None:
    """Where the blob of part ``obj`` should have its centroid relative to the part's projected centre, if the part
    were at its estimate: the centroid of the estimate's silhouette pixels that the depth does not show to be
    occluded (measured depth more than ``color_occluded_margin`` in front of the rendered surface) minus the
    centroid of the whole silhouette, pixels (du, dv). Sampled every ``stride`` pixels of the silhouette's
    bounding rectangle. None for meshes, an empty silhouette or one with less than a tenth of it visible."""
    if trk.meshes[obj] is not None:
        return None
    intr = trk.intrinsics
    est = trk.estimates[trk.names[obj]]
    umin, umax, vmin, vmax = render.bbox(trk, obj, est.t[None], est.R[None])
    h, w = depth.shape
    u0, u1 = max(int(np.floor(umin)), 0), min(int(np.ceil(umax)) + 1, w)
    v0, v1 = max(int(np.floor(vmin)), 0), min(int(np.ceil(vmax)) + 1, h)
    if u0 >= u1 or v0 >= v1:
        return None
    R = np.ascontiguousarray(est.R, np.float64)
    b = R @ trk.center[obj] + est.t  # box centre, camera frame
    n_sil, su, sv, n_seen, su_seen, sv_seen = _silhouette_sums(
        R, b, trk.half[obj], intr.fx, intr.fy, intr.cx, intr.cy, u0, u1, v0, v1, stride, depth,
        trk.config.color_occluded_margin)
    if n_sil < 4 or n_seen < 0.1 * n_sil:
        return None
    return np.array([su_seen / n_seen - su / n_sil, sv_seen / n_seen - sv / n_sil])


@nb.njit(cache=True)
def _silhouette_sums(R, b, half, fx, fy, cx, cy, u0, u1, v0, v1, stride, depth, margin):
    """Count and pixel-coordinate sums of the box's silhouette pixels (every ``stride``-th of the window) and of
    those not occluded (measured depth, NaN or ≤ 0 = none, more than ``margin`` in front of the box's surface).
    ``R`` body→camera rotation, ``b`` box centre (camera frame, m), ``half`` half extents (m)."""
    ox = -(R[0, 0] * b[0] + R[1, 0] * b[1] + R[2, 0] * b[2])
    oy = -(R[0, 1] * b[0] + R[1, 1] * b[1] + R[2, 1] * b[2])
    oz = -(R[0, 2] * b[0] + R[1, 2] * b[1] + R[2, 2] * b[2])
    n_sil = 0
    su = 0.0
    sv = 0.0
    n_seen = 0
    su_seen = 0.0
    sv_seen = 0.0
    for v in range(v0, v1, stride):
        ry = (v - cy) / fy
        for u in range(u0, u1, stride):
            rx = (u - cx) / fx
            z = _slab_depth(R[0, 0], R[1, 0], R[2, 0], R[0, 1], R[1, 1], R[2, 1], R[0, 2], R[1, 2], R[2, 2],
                            ox, oy, oz, half[0], half[1], half[2], rx, ry, 1.0)
            if not np.isfinite(z):
                continue
            n_sil += 1
            su += u
            sv += v
            d = depth[v, u]
            if d > 0.0 and np.isfinite(d) and d < z - margin:
                continue
            n_seen += 1
            su_seen += u
            sv_seen += v
    return n_sil, su, sv, n_seen, su_seen, sv_seen


def confident(trk, score: float, area) -> bool:
    """Is a detection with this ``score`` and blob ``area`` (pixels) confident enough to re-seed or follow a part
    (``reseed_min_score``, ``reseed_min_area_px``)? Its centroid may still be biased (a sliver): see
    ``reseed_min_area_ratio`` and :func:`far_sliver`."""
    cfg = trk.config
    return (score >= cfg.reseed_min_score and area is not None and bool(np.isfinite(area))
            and area >= cfg.reseed_min_area_px)


def blob_mask(trk, det, shape) -> np.ndarray | None:
    """Full-resolution mask of a detection's blob, eroded by 2 px (edges mix part and background); computed
    once per detection object and frame (colour input, re-seeding and ICP all use it)."""
    return _blob_entry(trk, det, shape)[1]


def blob_area(trk, det, shape) -> int:
    """Pixels of :func:`blob_mask` (0 without a mask), counted once when the mask is made."""
    return _blob_entry(trk, det, shape)[2]


def _blob_entry(trk, det, shape) -> tuple:
    """``(det, mask, area)`` of a detection this frame, made on first use."""
    key = id(det)
    entry = trk._blobs.get(key)
    if entry is None:
        mask, area = _make_blob_mask(trk, det, shape)
        entry = trk._blobs[key] = (det, mask, area)
    return entry


def make_blob_mask(trk, det, shape) -> np.ndarray | None:
    """The mask of :func:`blob_mask`, made afresh."""
    return _make_blob_mask(trk, det, shape)[0]


_ERODE_5 = np.ones((5, 5), np.uint8)
"""The blob masks' erosion kernel (2 px)."""


def _make_blob_mask(trk, det, shape) -> tuple[np.ndarray | None, int]:
    """:func:`make_blob_mask` and its pixel count (taken on the window the blob was drawn in)."""
    if det is None or getattr(det, "contour", None) is None:
        return None, 0
    if float(getattr(det, "score", 0.0) or 0.0) < trk.config.color_mask_min_score:
        return None, 0
    import cv2

    pts = np.asarray(det.contour, np.int32).reshape(-1, 2)
    bx, by, bw, bh = cv2.boundingRect(pts)  # the points' min and max: (bx, by), (bx + bw − 1, by + bh − 1)
    x0, y0 = max(bx - 3, 0), max(by - 3, 0)
    x1, y1 = min(bx + bw - 1 + 4, shape[1]), min(by + bh - 1 + 4, shape[0])
    m = np.zeros(shape, bool)
    if x0 >= x1 or y0 >= y1:
        return m, 0
    win = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.fillPoly(win, [pts - np.array([x0, y0], np.int32)], 1)
    eroded = cv2.erode(win, _ERODE_5)
    m[y0:y1, x0:x1] = eroded.astype(bool)
    return m, int(cv2.countNonZero(eroded))


def color_masks(trk, detections, gi, gj) -> tuple[np.ndarray, np.ndarray]:
    """Per part, which evaluated pixels lie inside its detected colour blob (dilated by one grid pixel)."""
    k = len(trk.parts)
    cmask = np.ones((k, gi.size), np.uint8)
    cvalid = np.zeros(k, np.uint8)
    cfg = trk.config
    if not (cfg.color_mask_likelihood and detections):
        return cmask, cvalid
    f = cfg.downsample
    grid = (trk._vs.size, trk._us.size)
    for i, name in enumerate(trk.names):
        det = detections.get(name)
        if det is None or trk.parts[i].color is None:
            continue
        if getattr(det, "center", None) is None:
            if trk._blob_seen[i] and cfg.color_mask_when_missing:
                # the detector, which has found this part's colour before, finds no blob now: the part shows
                # nowhere (empty mask), so depth that fits it (a hand over it) is no evidence for it
                cmask[i] = 0
                cvalid[i] = 1
            continue
        contour = getattr(det, "contour", None)
        if contour is None or float(getattr(det, "score", 0.0) or 0.0) < cfg.color_mask_min_score:
            continue
        trk._blob_seen[i] = True
        pts = (np.asarray(contour, np.float64).reshape(-1, 2) - trk._off) / f
        if pts.shape[0] < 3:
            continue
        grid_blob_pixels(np.round(pts).astype(np.int32), grid, gi, gj, cmask[i])
        cvalid[i] = 1
    return cmask, cvalid


def grid_blob_pixels(poly: np.ndarray, grid: tuple[int, int], gi: np.ndarray, gj: np.ndarray, out: np.ndarray) -> None:
    """Into ``out`` (P,) uint8: 1 where the grid pixel ``(gi, gj)`` (column, row) lies in the polygon ``poly`` ((V, 2)
    int32 grid coordinates) filled by ``cv2.fillPoly`` on a ``grid = (rows, cols)`` image and dilated by a 3 × 3
    square, else 0 — the values of ``cv2.dilate(fillPoly(zeros(grid)), ones((3, 3)))[gj, gi]``. Only the polygon's
    bounding box (plus a pixel, clipped to the grid) is filled: every filled pixel lies in it and the grid's clipping
    is kept where the box reaches the grid's edge; the 3 × 3 maximum is taken at the listed pixels only
    (:func:`_dilated_at`)."""
    import cv2

    rows, cols = grid
    x0 = max(int(poly[:, 0].min()) - 1, 0)
    x1 = min(int(poly[:, 0].max()) + 2, cols)
    y0 = max(int(poly[:, 1].min()) - 1, 0)
    y1 = min(int(poly[:, 1].max()) + 2, rows)
    if x0 >= x1 or y0 >= y1:  # off the grid: nothing filled
        out[:] = 0
        return
    win = np.zeros((y1 - y0, x1 - x0), np.uint8)
    cv2.fillPoly(win, [poly - np.array([x0, y0], np.int32)], 1)
    _dilated_at(win, y0, x0, gi, gj, out)


@nb.njit(cache=True)
def _dilated_at(win, y0, x0, gi, gj, out):
    """``out[p]`` = the maximum of the window ``win`` (uint8, top-left grid pixel ``(x0, y0)``; zero beyond it) over
    the 3 × 3 square centred on grid pixel ``(gi[p], gj[p])``: a 3 × 3 dilation (``cv2.dilate``'s values, whose border
    never adds a pixel) read at those pixels."""
    h, w = win.shape
    for p in range(gi.shape[0]):
        y = gj[p] - y0
        x = gi[p] - x0
        v = 0
        for yy in range(max(y - 1, 0), min(y + 2, h)):
            for xx in range(max(x - 1, 0), min(x + 2, w)):
                if win[yy, xx] > v:
                    v = win[yy, xx]
        out[p] = v


def area_ratio(trk, obj: int, area) -> float:
    """min(1, detected blob area / projected area of the part at its estimate); 1 when unknown.

    A part partly hidden by a hand has a blob whose centroid is biased toward the visible part, so the colour
    input is trusted in proportion to the visible fraction (an addition to eq. 3.7's score).
    """
    if area is None or not np.isfinite(area) or area <= 0:
        return 1.0
    est = trk.estimates[trk.names[obj]]
    intr = trk.intrinsics
    ok, uv = _hull_pixels(np.ascontiguousarray(trk.hulls[obj], np.float64), np.ascontiguousarray(est.R, np.float64),
                          est.t, float(intr.fx), float(intr.fy), float(intr.cx), float(intr.cy))
    if not ok:
        return 1.0
    import cv2

    expected = float(cv2.contourArea(cv2.convexHull(uv)))
    if expected <= 1.0:
        return 1.0
    return float(min(1.0, area / expected))


@nb.njit(cache=True)
def _hull_pixels(hull, R, t, fx, fy, cx, cy):
    """``(ok, uv)``: the hull points ``hull`` (V, 3, body frame) at ``(R, t)`` projected to pixels, float32 (V, 2), as
    ``intrinsics.project(pose.transform_points(hull)).astype(np.float32)`` gives them (``hull @ R.T + t`` with the
    fused multiply-adds of numpy's BLAS product of these shapes, :mod:`tracker.geometry.fma`; ``fx · x / z + cx``);
    ``ok`` False when a point lies closer than 1 cm to the camera plane."""
    n = hull.shape[0]
    uv = np.empty((n, 2), np.float32)
    for i in range(n):
        x, y, z = rigid_point(R, t, hull[i, 0], hull[i, 1], hull[i, 2])
        if z < 0.01:
            return False, uv
        uv[i, 0] = np.float32(fx * x / z + cx)
        uv[i, 1] = np.float32(fy * y / z + cy)
    return True, uv


def far_sliver(trk, obj: int, score: float, area, center) -> bool:
    """Is the blob a confident sliver of the part (score >= reseed_min_score, area >= reseed_min_area_px, but below
    reseed_min_area_ratio of the part's projection) whose centroid lies farther from the estimate's projected
    centre than ``far_sliver_radii`` × the part's projected bounding radius? A sliver's centroid is biased toward
    the visible piece by at most that radius, so it still says where the part went (a part snatched by a fast hand
    and mostly hidden in it); near the estimate the bias would outweigh the information."""
    cfg = trk.config
    if cfg.far_sliver_radii <= 0 or not confident(trk, score, area):
        return False
    est = trk.estimates[trk.names[obj]]
    c = est.R @ trk.center[obj] + est.t
    if c[2] <= 0.05:
        return False
    uv = trk.intrinsics.project(c[None])[0]
    rpx = trk._radius[obj] * trk.intrinsics.fx / float(c[2])
    return bool(np.hypot(uv[0] - center[0], uv[1] - center[1]) > cfg.far_sliver_radii * rpx)


def surface_fallback(trk, obj: int) -> float:
    return float(trk.half[obj].min())


def surface_depth(trk, obj: int, center) -> float:
    """Depth (m) of the part's estimate at pixel ``center`` (inf = the pixel is off its silhouette; meshes: the
    estimate's centre depth when the pixel is within its bounding radius, else inf)."""
    est = trk.estimates[trk.names[obj]]
    if trk.meshes[obj] is not None:
        uv = trk.intrinsics.project(est.t[None])[0]
        rpx = trk._radius[obj] * trk.intrinsics.fx / max(float(est.t[2]), 0.05)
        inside = np.hypot(uv[0] - center[0], uv[1] - center[1]) <= rpx
        return float(est.t[2]) - surface_fallback(trk, obj) if inside else np.inf
    intr = trk.intrinsics
    return _box_depth_at(np.ascontiguousarray(est.R, np.float64), est.t, trk.center[obj], trk.half[obj],
                         float(center[0]), float(center[1]), intr.fx, intr.fy, intr.cx, intr.cy)


@nb.njit(cache=True)
def _box_depth_at(R, t, center, half, u, v, fx, fy, cx, cy):
    """:func:`box_surface_depth` at one pixel ``(u, v)`` in one compiled call (the same renderer and float32 depth,
    without its per-call arrays): ``R`` (3, 3), ``t`` (3,) the pose, ``center``, ``half`` (3,) the box."""
    return box_depths(R, t, center, half, np.array([u]), np.array([v]), fx, fy, cx, cy)[0]


def box_surface_depth(trk, obj: int, pu: np.ndarray, pv: np.ndarray, pose: Pose | None = None) -> np.ndarray:
    """Depth (m) of box part ``obj``'s estimate (or ``pose``, camera frame) at full-resolution pixels ``(pu, pv)``
    (P,), inf off its silhouette."""
    est = trk.estimates[trk.names[obj]] if pose is None else pose
    p = len(pu)
    out = np.full((1, p), np.inf, np.float32)
    render_boxes_at_pixels(est.R[None, None], est.t[None, None], trk.center[obj:obj + 1], trk.half[obj:obj + 1], 0,
                           np.zeros(1, np.int64), pixel_rays(trk.intrinsics, pu, pv), np.asarray(pu, np.float64),
                           np.asarray(pv, np.float64), np.arange(p, dtype=np.int64), trk.intrinsics.fx,
                           trk.intrinsics.fy, trk.intrinsics.cx, trk.intrinsics.cy, out,
                           np.arange(p, dtype=np.int64)[None], np.zeros((1, p), np.uint8))
    return out[0].astype(np.float64)


def reseed(trk, obj: int, det, depth: np.ndarray) -> bool:
    """Re-draw ``reseed_fraction`` of part ``obj``'s particles (previous poses) around its colour blob: the
    centroid's ray at the blob's median depth plus half the part's smallest extent (std ``reseed_sigma``),
    velocity zero, orientation kept. The estimate is moved to the target as well. Returns whether it did."""
    cfg = trk.config
    mask = blob_mask(trk, det, depth.shape)
    if mask is None:
        return False
    est = trk.estimates[trk.names[obj]]
    target = blob_target(trk, obj, det, depth, mask)
    n = trk.p.shape[0]
    m = int(round(cfg.reseed_fraction * n))
    if m <= 0:
        return False
    sel = np.sort(trk.rng.choice(n, m, replace=False))
    trk.p[sel, obj] = target + trk.rng.normal(0.0, cfg.reseed_sigma, (m, 3))
    trk.v[sel, obj] = 0.0
    trk.estimates[trk.names[obj]] = Pose.from_rt(est.R, target)
    trk.n_reseeded += 1
    trk._carry.forget(obj)  # the jump to the blob is no motion of the part (hand-carry motion test)
    return True


def blob_target(trk: MultiObjectTracker, obj: int, det, depth: np.ndarray,
                mask: np.ndarray | None = None) -> np.ndarray:
    """Body origin (camera frame, m) that puts part ``obj``'s centre on the ray of its blob's centroid, at the blob's
    median depth plus half the part's smallest extent (without enough valid depth on the blob, e.g. in the sensor's
    shadow next to a hand: at the estimate's depth); the estimate's orientation is kept."""
    mask = blob_mask(trk, det, depth.shape) if mask is None else mask
    est = trk.estimates[trk.names[obj]]
    vals = depth[mask] if mask is not None else np.zeros(0)
    vals = vals[np.isfinite(vals) & (vals > 0)]
    if mask is not None and vals.size >= max(5, 0.2 * mask.sum()):
        zc = float(np.median(vals)) + surface_fallback(trk, obj)
    else:
        zc = float((est.R @ trk.center[obj] + est.t)[2])
    ray = pixel_rays(trk.intrinsics, np.array([float(det.center[0])]), np.array([float(det.center[1])]))[0]
    return ray * zc - est.R @ trk.center[obj]
