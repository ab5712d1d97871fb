"""Blob-follow stage (not in the seed; an addition of the tracker): a part seen in colour but not in depth moves
with its colour blob.

A cube grasped by a hand often shows a confident sliver of colour while the depth camera has (almost) nothing on
it: the hand covers most of it and its projector shadow takes the rest. The depth likelihood and the refinement
then have no evidence, and the hidden-part priors (rest and support) would hold the part where it was, while the
hand lifts it away. Between two frames in which the blob is confident and of about the same area, its centroid's
image motion is the part's own image motion (a changing occlusion would change the area too), so the part's
centre is moved by that motion, parallel to the image plane at its current depth, with its particles and rest
anchor; the rest and support priors are off for it in this frame (it is seen to move), and the motion counts for
the hand carry's motion test, so a part that then disappears in the hand is carried. With ``blob_follow_inside_px``
a part that is not carried is not followed while its blob stays inside the part's own projected footprint: a hand
coming over a resting part shrinks its blob and moves the centroid away from the hand without the part moving.

Pixels are full-resolution image coordinates; positions camera frame, metres.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from tracker.filter.camera_motion import move_part
from tracker.filter.colour_input import blob_mask, confident
from tracker.geometry.box_renderer import pixel_rays
from tracker.geometry.pose import Pose

if TYPE_CHECKING:
    from tracker.filter.frame_context import FrameContext
    from tracker.filter.particle_filter import MultiObjectTracker


def confident_blob(trk: MultiObjectTracker, det) -> tuple[np.ndarray, float] | None:
    """``(centroid (2,), area px)`` of a detection confident enough to follow (reseed_min_score, reseed_min_area_px,
    with an outline), else None."""
    if det is None or getattr(det, "center", None) is None or getattr(det, "contour", None) is None:
        return None
    area = getattr(det, "area", None)
    if not confident(trk, float(getattr(det, "score", 0.0) or 0.0), area):
        return None
    return np.asarray(det.center, np.float64), float(area)


def depth_poor(trk: MultiObjectTracker, det, depth: np.ndarray) -> bool:
    """Has the blob valid depth on fewer than ``blob_follow_max_depth_fraction`` of its pixels?"""
    mask = blob_mask(trk, det, depth.shape)
    if mask is None:
        return False
    n = int(np.count_nonzero(mask))
    if n == 0:
        return False
    vals = depth[mask]
    valid = int(np.count_nonzero(np.isfinite(vals) & (vals > 0)))
    return valid < trk.config.blob_follow_max_depth_fraction * n


def follow_blobs(trk: MultiObjectTracker, ctx: FrameContext, detections) -> np.ndarray:
    """Move every part seen in colour but not in depth with its blob (module docstring); returns (K,) bool, which
    parts moved this way (their rest and support priors are off this frame). "Not in depth": few valid depth
    values on the blob, or the last frame's dense-depth refinement of the part was not healthy."""
    cfg = trk.config
    k = len(trk.parts)
    moved = np.zeros(k, bool)
    blobs: list[tuple | None] = [None] * k  # (centroid, area), with blob_follow_overlap also the outline
    depth = ctx.depth
    if detections and depth is not None:
        for i, name in enumerate(trk.names):
            blob = confident_blob(trk, detections.get(name))
            if blob is not None and cfg.blob_follow_overlap:
                blob = (*blob, blob_window(detections.get(name)))
            blobs[i] = blob
    previous = trk._follow_blobs
    trk._follow_blobs = blobs
    trk._blob_uv_target = {}
    trk._blob_reappeared = np.array([b is not None and (previous is None or previous[i] is None)
                                     for i, b in enumerate(blobs)], bool)
    if not cfg.blob_follow or depth is None:
        return moved
    carried = trk._carry.carried
    for i, name in enumerate(trk.names):
        now, before = blobs[i], previous[i] if previous is not None else None
        if now is None or before is None:
            continue
        if abs(now[1] / before[1] - 1.0) > cfg.blob_follow_max_area_change:
            continue
        shift = now[0] - before[0]
        if float(np.hypot(*shift)) < cfg.blob_follow_min_px:
            continue
        if cfg.blob_follow_overlap and not moved_outline(outline_of(now), outline_of(before), shift):
            continue  # the outline only shrank where something came over it: an occlusion, not a motion
        if (cfg.blob_follow_inside_px > 0 and not carried[i]
                and inside_footprint(trk, i, detections.get(name), cfg.blob_follow_inside_px)
                and (not cfg.blob_follow_inside_covered or covered_now(trk, i, ctx))):
            continue  # the blob changed within the part's own footprint: something came over it
        last = trk._refiner.last[i] if trk._refiner is not None else None
        unsupported = last is None or not last.healthy  # the depth could not place it in the last frame
        if not (unsupported or depth_poor(trk, detections.get(name), depth)):
            continue
        c = centre(trk, i)
        if c[2] <= 0.05:
            continue
        uv = trk.intrinsics.project(c[None])[0] + shift
        if carried[i]:
            trk._blob_uv_target[i] = uv  # applied after the hand carry has moved it (in depth too): recentre()
        else:
            put_centre_on(trk, i, uv, anchor=not cfg.blob_follow_keep_anchor)
        moved[i] = True
    return moved


BlobWindow = tuple[int, int, np.ndarray]
"""``(x0, y0, mask)``: a blob's filled outline (bool, full-resolution pixels) in the window whose top-left pixel is
``(x0, y0)``."""


def blob_window(det) -> BlobWindow | None:
    """The filled outline of a detection's blob (not eroded), or None without one."""
    contour = getattr(det, "contour", None) if det is not None else None
    if contour is None:
        return None
    import cv2

    pts = np.asarray(contour, np.int32).reshape(-1, 2)
    if pts.shape[0] < 3:
        return None
    x0, y0 = int(pts[:, 0].min()), int(pts[:, 1].min())
    w, h = int(pts[:, 0].max()) - x0 + 1, int(pts[:, 1].max()) - y0 + 1
    win = np.zeros((h, w), np.uint8)
    cv2.fillPoly(win, [pts - np.array([x0, y0], np.int32)], 1)
    return x0, y0, win.astype(bool)


def overlap(now: BlobWindow, before: BlobWindow, dx: int, dy: int) -> int:
    """Pixels of blob ``now`` that blob ``before``, moved by ``(dx, dy)`` pixels, covers."""
    x0, y0, wn = now
    bx0, by0, wb = before
    ys, xs = np.nonzero(wn)
    xs = xs + (x0 - dx - bx0)
    ys = ys + (y0 - dy - by0)
    ok = (xs >= 0) & (ys >= 0) & (xs < wb.shape[1]) & (ys < wb.shape[0])
    return int(np.count_nonzero(wb[ys[ok], xs[ok]]))


def outline_of(blob: tuple | None) -> BlobWindow | None:
    """The outline kept with a followed blob ``(centroid, area[, outline])`` (``blob_follow_overlap``), or None."""
    return blob[2] if blob is not None and len(blob) > 2 else None


def moved_outline(now: BlobWindow | None, before: BlobWindow | None, shift: np.ndarray) -> bool:
    """Does the blob's outline show the motion its centroid shift (pixels) says (``blob_follow_overlap``)? It does
    when last frame's outline moved by the shift covers more of this frame's blob than it does unmoved. A hand
    coming over a resting part takes pixels off one side of its blob: the centroid moves away from the hand, but the
    blob left is still inside the old outline, which unmoved covers it best. Without outlines: True."""
    if now is None or before is None:
        return True
    dx, dy = (int(round(float(v))) for v in shift)
    if dx == 0 and dy == 0:
        return False
    return overlap(now, before, dx, dy) > overlap(now, before, 0, 0)


def footprint(trk: MultiObjectTracker, obj: int, pose: Pose | None = None) -> tuple[float, float, float, float] | None:
    """Image bounds ``(u_min, v_min, u_max, v_max)`` (full-resolution pixels) of part ``obj``'s bounding-box corners
    at its estimate (or ``pose``, camera frame), or None when a corner lies closer than 5 cm to the camera."""
    est = trk.estimates[trk.names[obj]] if pose is None else pose
    pts = trk.corners[obj] @ est.R.T + est.t
    if np.any(pts[:, 2] < 0.05):
        return None
    uv = trk.intrinsics.project(pts)
    return float(uv[:, 0].min()), float(uv[:, 1].min()), float(uv[:, 0].max()), float(uv[:, 1].max())


def inside_footprint(trk: MultiObjectTracker, obj: int, det, margin_px: float) -> bool:
    """Does the bounding box ``(x, y, w, h)`` of part ``obj``'s blob lie inside the part's :func:`footprint` grown by
    ``margin_px`` pixels on every side (``blob_follow_inside_px``)? False without a box or a footprint."""
    bbox = getattr(det, "bbox", None) if det is not None else None
    fp = footprint(trk, obj) if bbox is not None else None
    if fp is None:
        return False
    x, y, w, h = (float(v) for v in bbox)
    u0, v0, u1, v1 = fp
    return bool(x >= u0 - margin_px and y >= v0 - margin_px and x + w <= u1 + margin_px and y + h <= v1 + margin_px)


def covered_now(trk: MultiObjectTracker, obj: int, ctx: FrameContext) -> bool:
    """``blob_follow_inside_covered``: is part ``obj``'s footprint covered in this frame's depth (something nearer than
    its surface over most of it, no table showing: :func:`~tracker.filter.footprint_depth.covered`)? False without
    depth."""
    from tracker.filter.footprint_depth import classify_footprint, covered

    if ctx.depth is None:
        return False
    return covered(classify_footprint(trk, obj, ctx.depth, ctx.table_plane))


def centre(trk: MultiObjectTracker, obj: int) -> np.ndarray:
    """Camera-frame centre (m) of part ``obj``'s estimate."""
    est = trk.estimates[trk.names[obj]]
    return est.R @ trk.center[obj] + est.t


def put_centre_on(trk: MultiObjectTracker, obj: int, uv: np.ndarray, anchor: bool = True) -> None:
    """Translate part ``obj`` parallel to the image plane so that its centre, at its current depth, projects to
    the pixel ``uv`` (its rest anchor with it unless ``anchor`` is False)."""
    c = centre(trk, obj)
    if c[2] <= 0.05:
        return
    d = pixel_rays(trk.intrinsics, np.array([uv[0]]), np.array([uv[1]]))[0] * c[2] - c
    move_part(trk, obj, np.eye(3), d, anchor)


def recentre(trk: MultiObjectTracker, obj: int) -> None:
    """After the hand carry moved part ``obj``: put its centre on the ray of the image position its blob says
    (:func:`follow_blobs`), at the depth the carry gave it (the blob says nothing about depth, the hand does)."""
    uv = trk._blob_uv_target.get(obj)
    if uv is not None:
        put_centre_on(trk, obj, uv)
