"""Quiet parts: which parts may skip their coordinate pass this frame (a speed setting, not in the seed).

A part that rests in full view costs as much in the coordinate passes (noise, render of all N particles,
likelihood, resampling) as one that moves, yet the dense-depth refinement after the filter already holds it to the
depth. A part is *quiet* in a frame when all of these hold:

* last frame's refinement of it was accepted and its correction was small (``quiet_max_correction_m`` at the
  part's centre, ``quiet_max_correction_deg``): the filter's prediction was already where the depth put it;
* it has a reliable colour blob now and had a confident one last frame, of about the same area
  (``quiet_max_area_change``), whose centroid moved in the image by what the prediction says the part moved, within
  ``quiet_max_px`` pixels (a hand that takes or covers it changes the blob; a swaying camera moves blob and
  prediction together under the constant-velocity model);
* it is well visible (``visible_fraction_full``), not carried, not touched by a tracked hand, not just released, not
  followed by its blob (:mod:`tracker.filter.blob_follow`) and its blob lies on its estimate;
* it has skipped fewer than ``quiet_max_skips`` passes in a row (a full pass then re-spreads its particles).
* with ``quiet_max_residual_m`` > 0, this frame's depth is explained at its prediction (:func:`depth_explained`:
  sample points on its camera-facing box faces, at its last estimate moved by the prediction, lie on the measured
  depth): a hand reaching over it or a push shows in the depth of the frame it happens in, before the blob or the
  refinement says so. Mesh parts are then never quiet.

A quiet part keeps its noise-free prediction (its particles as they are, moved by the motion model) and the
likelihood of that prediction, which the first full render of the frame has already evaluated; its pass is skipped.
The same skip serves one accuracy setting, whatever ``quiet_skip`` says: ``carry_hidden_skip``, a part hidden in the
hand that has just moved it.

Two lighter settings keep a quiet part's pass (its particles keep their noise, likelihood and resampling, so its
cloud keeps its spread for when a hand takes it) and only make it cheaper: ``quiet_thin`` evaluates its likelihood
on the smaller pixel budget ``quiet_pixels_per_part`` (the refinement restores the precision), and
``quiet_refine_last`` > 0 refines it with only the last (finest) correspondence thresholds of the dense refinement
(last frame's correction was small and the depth shows it at its prediction: the coarse thresholds only re-find
where it already is); ``quiet_converged_rotation`` / ``_translation`` end its Gauss-Newton updates once one
turns and moves it by less than these (after the coarsest threshold). ``quiet_refine_skip`` does not refine it
this frame (it keeps the filter's estimate, or with ``quiet_refine_hold`` its noise-free prediction's mean pose,
``trk._held_poses``); having no correction to remember, it is not quiet the next frame and is refined then.
Pixels: full-resolution image coordinates; positions camera frame, metres.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numba as nb
import numpy as np

from tracker.filter.blob_follow import confident_blob
from tracker.filter.motion_model import mean_poses
from tracker.filter.resampling import normalize_log_weights

if TYPE_CHECKING:
    from tracker.filter.frame_context import FrameContext
    from tracker.filter.particle_filter import MultiObjectTracker


def _centre_px(trk: MultiObjectTracker, i: int, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Image position (2,) of part ``i``'s body centre at pose ``(R, t)``."""
    c = R @ trk.center[i] + t
    intr = trk.intrinsics
    z = max(float(c[2]), 1e-3)
    return np.array([intr.fx * c[0] / z + intr.cx, intr.fy * c[1] / z + intr.cy])


def face_points(half: np.ndarray, center: np.ndarray, per_side: int = 4, extent: float = 0.8) -> np.ndarray:
    """Sample points of a box's six faces (body frame, metres): a ``per_side`` × ``per_side`` grid over the inner
    ``extent`` of each face (away from its edges, where a small pose error meets a depth discontinuity), as rows
    ``(x, y, z, nx, ny, nz)`` with the face's outward normal; (6 · per_side², 6)."""
    half = np.asarray(half, np.float64)
    g = (np.arange(per_side) + 0.5) / per_side * 2.0 - 1.0
    a, b = (x.ravel() * extent for x in np.meshgrid(g, g, indexing="ij"))
    rows = []
    for axis in range(3):
        o1, o2 = (axis + 1) % 3, (axis + 2) % 3
        for sign in (-1.0, 1.0):
            pts = np.zeros((a.size, 6))
            pts[:, axis] = sign * half[axis]
            pts[:, o1] = a * half[o1]
            pts[:, o2] = b * half[o2]
            pts[:, 3 + axis] = sign
            rows.append(pts)
    out = np.concatenate(rows)
    out[:, :3] += np.asarray(center, np.float64)
    return out


def _faces_of(trk: MultiObjectTracker, i: int) -> np.ndarray:
    """:func:`face_points` of box part ``i``, made once per tracker (``trk._quiet_faces``)."""
    if i not in trk._quiet_faces:
        trk._quiet_faces[i] = np.ascontiguousarray(face_points(trk.half[i], trk.center[i]))
    return trk._quiet_faces[i]


def depth_explained(depth: np.ndarray | None, intr, faces: np.ndarray, R: np.ndarray, t: np.ndarray, tol: float,
                    min_inliers: float) -> bool:
    """Does ``depth`` (H×W float32 metres, NaN = none) show a box at pose ``(R, t)`` (camera frame)? Its face points
    ``faces`` (:func:`face_points`) on faces turned to the camera are projected to their nearest pixels; at least
    half of them must fall on the image with depth and at least ``min_inliers`` of those must lie within ``tol``
    metres of the predicted depth (a hand or another part in front counts against it, as does a part that has moved
    away)."""
    if depth is None:
        return False
    n_facing, n_valid, n_good = _face_residuals(depth, faces, np.ascontiguousarray(R, np.float64),
                                                np.ascontiguousarray(t, np.float64), intr.fx, intr.fy, intr.cx,
                                                intr.cy, float(tol))
    if n_facing == 0 or n_valid < 0.5 * n_facing:
        return False
    return n_good >= min_inliers * n_valid


@nb.njit(cache=True)
def _face_residuals(depth, faces, R, t, fx, fy, cx, cy, tol):
    """For :func:`depth_explained`: how many face points face the camera, how many of them land on the image with
    a depth, and how many of those lie within ``tol`` of it; (0, 0, 0) when a facing point lies within 5 cm of the
    camera plane."""
    h, w = depth.shape
    n_facing = 0
    n_valid = 0
    n_good = 0
    for r in range(faces.shape[0]):
        x = R[0, 0] * faces[r, 0] + R[0, 1] * faces[r, 1] + R[0, 2] * faces[r, 2] + t[0]
        y = R[1, 0] * faces[r, 0] + R[1, 1] * faces[r, 1] + R[1, 2] * faces[r, 2] + t[1]
        z = R[2, 0] * faces[r, 0] + R[2, 1] * faces[r, 1] + R[2, 2] * faces[r, 2] + t[2]
        nx = R[0, 0] * faces[r, 3] + R[0, 1] * faces[r, 4] + R[0, 2] * faces[r, 5]
        ny = R[1, 0] * faces[r, 3] + R[1, 1] * faces[r, 4] + R[1, 2] * faces[r, 5]
        nz = R[2, 0] * faces[r, 3] + R[2, 1] * faces[r, 4] + R[2, 2] * faces[r, 5]
        if nx * x + ny * y + nz * z >= 0.0:
            continue
        if z < 0.05:
            return 0, 0, 0
        n_facing += 1
        u = int(np.rint(fx * x / z + cx))
        v = int(np.rint(fy * y / z + cy))
        if u < 0 or u >= w or v < 0 or v >= h:
            continue
        zd = depth[v, u]
        if not (zd > 0.0):  # NaN or no measurement
            continue
        n_valid += 1
        if abs(zd - z) <= tol:
            n_good += 1
    return n_facing, n_valid, n_good


def quiet_parts(trk: MultiObjectTracker, ctx: FrameContext, detections, detected: np.ndarray,
                pred: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """(K,) bool: the parts whose coordinate pass is skipped this frame (module docstring), also kept as
    ``trk._quiet_now``; the quiet parts themselves (whether or not their pass is skipped) as ``trk._settled``.
    ``pred``: the noise-free prediction (p (N, K, 3), R (N, K, 3, 3), v) of this frame. None is quiet unless
    a setting of :func:`detection_on` is on."""
    cfg = trk.config
    k = len(trk.parts)
    quiet = np.zeros(k, bool)
    trk._settled = np.zeros(k, bool)
    trk._held_poses = {}
    memory = trk._quiet_memory
    trk._quiet_memory = None  # one frame old at most: set again after this frame's refinement
    if cfg.carry_hidden_skip > 0:
        # hidden in the hand that has just moved it: the depth shows the hand, not the part, and the pass would only
        # spread it over the hand's surface; the hand's registration is its motion
        quiet |= trk._carry_moved & ~detected & (trk.visibility < cfg.carry_hidden_skip)
    if cfg.carry_start_skip:
        # a carry's first frame: the hand's registration places it, not the likelihood on its few visible pixels
        quiet |= trk._carry_started
    if not detection_on(cfg) or memory is None or not detections:
        trk._quiet_skips[:] = 0
        trk._quiet_now = quiet
        return quiet
    last_blob, last_px, small_fresh, small_held = memory
    # quiet_skip_held: a part held last frame (not refined) keeps the small correction it was held on for its pass;
    # the refinement still needs a fresh one (so a held part is refined at least every other frame)
    small = small_fresh | small_held if (cfg.quiet_skip_held and cfg.quiet_refine_skip) else small_fresh
    fresh = np.zeros(k, bool)
    w = normalize_log_weights(trk.log_w)
    carried = trk._carry.carried
    for i, name in enumerate(trk.names):
        if not (small[i] and detected[i] and last_blob[i] is not None) or (
                cfg.quiet_skip and trk._quiet_skips[i] >= cfg.quiet_max_skips):
            continue
        if (carried[i] or trk._was_carried[i] or name in ctx.touched or trk._blob_moved[i] or trk._blob_off[i]
                or trk.visibility[i] < cfg.visible_fraction_full):
            continue
        blob = confident_blob(trk, detections.get(name))
        if blob is None or abs(blob[1] / last_blob[i][1] - 1.0) > cfg.quiet_max_area_change:
            continue
        # the prediction's image motion of the part's centre (weighted mean of the particles' centres)
        c_pred = np.einsum("n,nij,j->i", w, pred[1][:, i], trk.center[i]) + w @ pred[0][:, i]
        intr = trk.intrinsics
        z = max(float(c_pred[2]), 1e-3)
        px_pred = np.array([intr.fx * c_pred[0] / z + intr.cx, intr.fy * c_pred[1] / z + intr.cy])
        if np.linalg.norm((blob[0] - last_blob[i][0]) - (px_pred - last_px[i])) > cfg.quiet_max_px:
            continue
        if cfg.quiet_max_residual_m > 0:
            est = trk.estimates[name]
            shift = w @ pred[0][:, i] - w @ trk.p[:, i]  # the prediction's motion of the part (weighted mean)
            if trk.parts[i].box is None or not depth_explained(
                    ctx.depth, intr, _faces_of(trk, i), est.R, est.t + shift,
                    cfg.quiet_max_residual_m, cfg.quiet_min_inliers):
                continue
        fresh[i] = True
    trk._settled = fresh & small_fresh  # held this frame: quiet on a fresh small correction
    if cfg.quiet_refine_skip and cfg.quiet_refine_hold and trk._settled.any():
        # where a quiet part is held this frame: its noise-free prediction's mean pose
        sel = np.flatnonzero(trk._settled)
        if cfg.quiet_refine_hold_last:  # where it rests: last frame's estimate (moved with the camera)
            trk._held_poses = {int(i): trk.estimates[trk.names[i]] for i in sel}
        else:
            trk._held_poses = dict(zip(sel.tolist(), mean_poses(pred[0][:, sel], pred[1][:, sel], w), strict=True))
    if cfg.quiet_skip:
        quiet |= fresh
        trk._quiet_skips = np.where(quiet, trk._quiet_skips + 1, 0)
        trk.n_quiet_skipped += int(quiet.sum())
    else:
        trk._quiet_skips[:] = 0
    trk.n_settled += int(trk._settled.sum())
    trk._quiet_now = quiet
    return quiet


def detection_on(cfg) -> bool:
    """Is any setting on that acts on quiet parts (``quiet_skip``, ``quiet_thin``, ``quiet_refine_last``,
    ``quiet_converged_rotation``, ``quiet_refine_skip``)?"""
    return bool(cfg.quiet_skip or cfg.quiet_thin or cfg.quiet_refine_last > 0 or cfg.quiet_converged_rotation > 0
                or cfg.quiet_refine_skip)


def remember(trk: MultiObjectTracker, detections, poses: dict, corrections: list) -> None:
    """After the refinement: keep what :func:`quiet_parts` compares against next frame — each part's confident blob,
    the image position of its final estimate's centre and whether its accepted correction was small
    (``corrections[k]``: the refinement's :class:`~tracker.refine.part_refiner.Correction` or None)."""
    cfg = trk.config
    if not detection_on(cfg):
        return
    k = len(trk.parts)
    blobs = [confident_blob(trk, detections.get(n)) if detections else None for n in trk.names]
    px = np.zeros((k, 2))
    small = np.zeros(k, bool)
    max_rad = np.radians(cfg.quiet_max_correction_deg)
    for i, name in enumerate(trk.names):
        pose = poses[name]
        px[i] = _centre_px(trk, i, pose.R, pose.t)
        corr = corrections[i]
        if corr is None:
            continue
        c_new = corr.R @ trk.center[i] + corr.t
        c_old = corr.Rd.T @ (c_new - corr.td)
        angle = float(np.arccos(np.clip((np.trace(corr.Rd) - 1.0) / 2.0, -1.0, 1.0)))
        small[i] = np.linalg.norm(c_new - c_old) <= cfg.quiet_max_correction_m and angle <= max_rad
    # quiet_skip_held: a part held this frame (no correction) was quiet on a small correction, which it remembers
    # until its next refinement (quiet_parts reset _settled this frame: without memory no part is held)
    held = trk._settled.copy() if (cfg.quiet_skip_held and cfg.quiet_refine_skip) else np.zeros(k, bool)
    trk._quiet_memory = (blobs, px, small, held)
