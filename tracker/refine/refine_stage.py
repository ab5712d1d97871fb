"""Refinement stage of the tracker, after the filter's estimate (spec ``depth-refinement.md``).

With ``dense_refinement`` (the default preset) every visible part is refined by dense-depth Gauss-Newton
(:mod:`tracker.refine.part_refiner`) and lost or just released parts are re-acquired
(:mod:`tracker.refine.recovery`); with ``icp_refinement`` alone, well-visible parts get the older point-to-plane
ICP (:mod:`tracker.refine.icp_refinement`). Either way the part's particles move rigidly with the accepted
correction, so that the next prediction starts at the refined pose. Camera frame, metres.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from tracker.filter import quiet_parts
from tracker.filter.colour_input import blob_area, blob_mask, blob_target
from tracker.filter.frame_context import table_normal_offset
from tracker.filter.penalties import intersection_flags
from tracker.filter.resampling import normalize_log_weights
from tracker.geometry.pose import Pose
from tracker.refine import table_silhouette
from tracker.refine.dense_depth import RefineResult, RefineSettings
from tracker.refine.icp_refinement import PartSurfaceModel, icp_refine, part_points
from tracker.refine.part_refiner import PartRefiner
from tracker.refine.recovery import CUBE_STARTS, CUBE_TURNS_DEG, MESH_STARTS, reacquire, turns_about
from tracker.refine.region_term import RegionSettings

if TYPE_CHECKING:
    from tracker.filter.particle_filter import MultiObjectTracker, TrackerState


def refine(trk: MultiObjectTracker, state: TrackerState, depth, detections, table, frame_depth=None) -> None:
    """Refine ``state``'s poses in place (and the tracker's particles) as the settings say (module docstring).
    ``depth``: the depth to refine on (occluder pixels such as a hand's removed); ``frame_depth``: the frame's own
    depth, with which the silhouette term sees what hides a part's outline (``depth`` when None)."""
    cfg = trk.config
    if cfg.dense_refinement and depth is not None:
        plane = table_normal_offset(table)
        dense_refine(trk, state, depth, detections, plane, frame_depth)
    elif cfg.icp_refinement:
        icp_refine_parts(trk, state, depth, detections, table)


def icp_refine_parts(trk: MultiObjectTracker, state: TrackerState, depth, detections, table) -> None:
    """ICP refinement of well-visible parts (see :mod:`tracker.refine.icp_refinement`); shifts their particles."""
    cfg = trk.config
    plane = table_normal_offset(table)
    for i, name in enumerate(trk.names):
        if trk.visibility[i] < cfg.icp_min_visibility:
            continue
        det = detections.get(name) if detections else None
        coloured = trk.parts[i].color is not None and bool(detections)
        est = state.poses[name]
        ref = reuse_icp(trk, i, est, det) if coloured else None
        fresh = ref is None
        if fresh:
            blob = None
            if coloured:
                blob = blob_mask(trk, det, depth.shape)
                if blob is None:  # a coloured part that is not detected now: do not trust nearby points
                    trk._icp_last[i] = None
                    continue
            if trk._surface[i] is None:
                trk._surface[i] = PartSurfaceModel(trk.parts[i])
            others = np.array([state.poses[n].t for n in trk.names if n != name]).reshape(-1, 3)
            pts = part_points(depth, trk.intrinsics, est, trk._radius[i] + 0.005, blob, plane, cfg.icp_stride,
                              others=others)
            ref = icp_refine(trk._surface[i], pts, est, cfg.icp_iterations)
            trk._icp_last[i] = None
            if ref is None:
                continue
        Rd = ref.R @ est.R.T
        angle = float(np.arccos(np.clip((np.trace(Rd) - 1.0) / 2.0, -1.0, 1.0)))
        if np.linalg.norm(ref.t - est.t) > cfg.icp_max_translation or angle > cfg.icp_max_rotation:
            trk._icp_last[i] = None
            continue
        if intersects_others(trk, i, ref, state.poses):
            trk._icp_last[i] = None
            continue
        if fresh and det is not None and getattr(det, "center", None) is not None:
            trk._icp_last[i] = (ref, np.asarray(det.center, np.float64), float(getattr(det, "area", 0) or 0), 0)
        trk.p[:, i] = (trk.p[:, i] - est.t) @ Rd.T + ref.t
        trk.R[:, i] = Rd @ trk.R[:, i]
        state.poses[name] = ref
        state.particles[name] = trk.p[:, i].astype(np.float32)
        trk.estimates[name] = ref


def make_refiner(trk: MultiObjectTracker) -> PartRefiner:
    cfg = trk.config
    shapes = []
    for i in range(len(trk.parts)):
        mesh = trk.meshes[i]
        if mesh is None:
            shapes.append(("box", trk.center[i].copy(), trk.half[i].copy()))
        else:
            shapes.append(("mesh", np.ascontiguousarray(mesh.vertices, np.float64),
                           np.ascontiguousarray(mesh.faces, np.int64)))
    settings = RefineSettings(
        thresholds=tuple(cfg.refine_thresholds), updates_per_iteration=cfg.refine_updates,
        occlusion_m=cfg.refine_occlusion, lambda_rot=cfg.refine_lambda_rot, lambda_trans=cfg.refine_lambda_trans,
        min_valid_fraction=cfg.refine_min_valid_fraction, max_points=cfg.refine_max_points,
        few_points_position=cfg.refine_few_points_position,
        converged_step=cfg.refine_converged_step, converged_rotation=cfg.refine_converged_rotation,
        converged_translation=cfg.refine_converged_translation, bilinear_m=cfg.refine_bilinear_m,
        outline_per_threshold=cfg.refine_outline_per_threshold,
    )
    region = (RegionSettings(weight=cfg.refine_region_weight, depth_agree_m=cfg.refine_region_depth_agree,
                             normal_cos=cfg.refine_region_normal_cos, lines=cfg.refine_region_lines)
              if cfg.refine_region_weight > 0 else None)
    short = None
    if cfg.quiet_refine_last > 0:
        short = dataclasses.replace(settings, thresholds=tuple(cfg.refine_thresholds)[-int(cfg.quiet_refine_last):])
    if cfg.quiet_converged_rotation > 0:  # quiet parts end their updates once converged
        short = dataclasses.replace(settings if short is None else short,
                                    converged_rotation=cfg.quiet_converged_rotation,
                                    converged_translation=cfg.quiet_converged_translation)
    return PartRefiner(trk.intrinsics, shapes, list(trk.center), trk.corners, settings, cfg.refine_stride,
                       cfg.refine_max_translation, cfg.refine_max_rotation, region, short)


def dense_refine(trk: MultiObjectTracker, state: TrackerState, depth: np.ndarray, detections,
                 plane: tuple[np.ndarray, float] | None = None, frame_depth: np.ndarray | None = None) -> None:
    """Dense-depth refinement of every visible part (:mod:`tracker.refine.part_refiner`) and re-acquisition of
    lost or just released parts (:mod:`tracker.refine.recovery`); the particles move with each accepted
    correction. A coloured part is refined only on the pixels of its colour blob (hands and other parts left out)
    and not at all while its blob is missing. ``plane``: the table plane ``(normal, offset)`` (camera frame) or None:
    cubes are then also re-acquired from turns about its normal (a part put down on the table differs from its
    estimate by such a turn), and resting parts the depth does not place are fitted on it from their colour outline
    (:mod:`tracker.refine.table_silhouette`)."""
    k = len(trk.parts)
    poses, active, allowed, visible, outlines = [], [], [], [], []
    for i, name in enumerate(trk.names):
        est = state.poses[name]
        poses.append((est.R, est.t))
        mask = None
        seen = bool(trk.visibility[i] >= trk.config.visible_fraction_full)
        ok = bool(trk.visibility[i] > 0.05)
        if trk.parts[i].color is not None and detections:
            det = detections.get(name)
            mask = blob_mask(trk, det, depth.shape) if det is not None else None
            area = 0 if mask is None else blob_area(trk, det, depth.shape)
            seen = area >= trk.config.reseed_min_area_px
            ok = ok and area > 0  # no blob: the part shows nowhere, nothing to refine on
        active.append(ok)
        allowed.append(mask)
        visible.append(seen)
        outlines.append(None if mask is None else getattr(detections.get(name), "contour", None))
    short = None
    if trk.config.quiet_refine_last > 0 or trk.config.quiet_converged_rotation > 0:
        # quiet parts: the finest thresholds only, or an early end once converged (filter/quiet_parts.py)
        short = [bool(x) for x in trk._settled]
    # quiet_refine_skip: a quiet part keeps the filter's estimate this frame (no correction to remember: it is not
    # quiet next frame, so it is refined at least every other frame); no loss count, no re-acquisition, no table fit
    held = np.asarray(trk._settled, bool) if trk.config.quiet_refine_skip else np.zeros(k, bool)
    active = [a and not h for a, h in zip(active, held, strict=True)]
    before = list(trk._refiner.last)
    corrections = trk._refiner.refine(depth, poses, active, allowed, outlines, frame_depth, short)
    for i in np.flatnonzero(held):
        # the later stages read ``last`` as "the depth placed it": a held part was placed last frame (its correction
        # was small), so it keeps that result (not moved with the scene, still a landmark, not followed by its blob)
        trk._refiner.last[i] = before[i]
    placed = table_silhouette.place_on_table(trk, poses, corrections, detections, plane, frame_depth, held)
    trk.silhouette_placed = placed
    carried = np.asarray(trk._carry.carried, bool).copy()
    released = trk._was_carried & ~carried
    trk._was_carried = carried
    trk._cooldown = np.maximum(trk._cooldown - 1, 0)
    hold = trk.config.quiet_refine_hold
    for i in range(k):
        if held[i]:
            pose = trk._held_poses.get(i) if hold else None
            if pose is not None:  # held at its prediction: the particles' mean moves there
                res = RefineResult(pose.R, pose.t, True, 0, 0, 0.0, float("nan"), reason="held at its prediction")
                corrections[i] = trk._refiner.correction(poses[i][0], poses[i][1], res)
            continue
        if placed[i]:  # placed by its colour outline on the table: not re-acquired from its sliver of depth
            trk._loss.reset(i)
            continue
        res = trk._refiner.last[i]
        supported = res if corrections[i] is not None else None
        need = trk._loss.update(i, supported, visible[i] and not carried[i], bool(released[i]))
        beyond = res is not None and res.healthy and corrections[i] is None  # supported, but a large correction
        start, current = poses[i], res
        if visible[i] and allowed[i] is not None and trk._blob_off[i]:
            # the part's blob lay off its estimate (colour stage): start from the blob (its centroid's ray, its
            # median depth); the refinement from the estimate (``res``) stays a candidate (a hand may bias the blob)
            need = True
            start, current = (poses[i][0], blob_target(trk, i, detections.get(trk.names[i]), depth)), None
        if trk.config.reacquire and (need or beyond) and trk._cooldown[i] == 0 and visible[i]:
            starts = CUBE_STARTS if trk.parts[i].box is not None else MESH_STARTS
            if plane is not None and trk.parts[i].box is not None:
                starts = np.concatenate([starts, turns_about(plane[0], CUBE_TURNS_DEG)])
            if carried[i] and trk.config.carry_reacquire_keep_turn:
                starts = starts[:1]  # in the hand: the hand's motion has turned it, a sliver of it may not
            up = plane[0] if plane is not None and trk.parts[i].box is not None else None
            found = reacquire(trk._refiner, depth, i, start[0], start[1], allowed[i], starts, current, outlines[i],
                              frame_depth, up=up, tilt_gain=trk.config.reacquire_tilt_gain)
            if current is None and res is not None and res.healthy and (found is None or res.score >= found.score):
                found = res
            res = found
            trk._cooldown[i] = trk.config.reacquire_cooldown
            trk.n_reacquired += 1
            if res is not None:
                corrections[i] = trk._refiner.correction(poses[i][0], poses[i][1], res)
                trk.v[:, i] = 0.0
                trk._loss.reset(i)
    applied = [None] * k
    stack = None  # the estimates stacked for intersects_others, made once and kept up to date
    for i, corr in enumerate(corrections):
        if corr is None:
            continue
        name = trk.names[i]
        ref = Pose.from_rt(corr.R, corr.t)
        # (a held part stays where its last refinement, which passed this test, put it: not tested against the
        # filter's estimates of its neighbours, which may touch it)
        if stack is None and k > 1:
            stack = pose_stack(trk, state.poses)
        if not held[i] and intersects_others(trk, i, ref, state.poses, stack):
            continue
        trk.p[:, i], trk.R[:, i] = corr.apply_to(trk.p[:, i], trk.R[:, i])
        if not held[i] and trk.config.refined_collapse_m > 0 and spread(trk, i) > trk.config.refined_collapse_m:
            trk.p[:, i], trk.R[:, i], trk.v[:, i] = ref.t, ref.R, 0.0  # refined_collapse_m: kept where the depth put it
        state.poses[name] = ref
        if stack is not None:
            stack[0][0, i], stack[1][0, i] = ref.R, ref.t
        state.particles[name] = trk.p[:, i].astype(np.float32)
        trk.estimates[name] = ref
        applied[i] = corr
        if placed[i]:  # the rest prior holds it here, not where it was last seen with its depth
            trk._rest_t[i] = corr.t.copy()
            trk._rest_R[i] = corr.R.copy()
    # a held part's correction is not the depth's: it is not remembered (so the part is refined next frame)
    quiet_parts.remember(trk, detections, state.poses, [None if h else c for h, c in zip(held, applied, strict=True)])


def spread(trk: MultiObjectTracker, obj: int) -> float:
    """Spread (m) of part ``obj``'s particle positions: the norm of their per-axis standard deviations under the
    particle weights (camera frame)."""
    w = normalize_log_weights(trk.log_w)
    p = trk.p[:, obj]
    mean = w @ p
    return float(np.sqrt(w @ ((p - mean) ** 2).sum(1)))


def reuse_icp(trk: MultiObjectTracker, obj: int, est: Pose, det) -> Pose | None:
    """The last ICP result of a part whose colour blob has not moved since (``icp_reuse_px``), else None: the
    depth points ICP would use are the same, so would be its answer; saves the registration."""
    cfg = trk.config
    last = trk._icp_last[obj]
    if cfg.icp_reuse_px <= 0.0 or last is None or det is None or last[3] >= cfg.icp_max_skipped:
        return None
    center = getattr(det, "center", None)
    if (center is None or getattr(det, "contour", None) is None
            or float(getattr(det, "score", 0.0) or 0.0) < cfg.color_mask_min_score):
        return None
    area = float(getattr(det, "area", 0) or 0)
    if np.linalg.norm(np.asarray(center, np.float64) - last[1]) > cfg.icp_reuse_px:
        return None
    if last[2] <= 0 or abs(area / last[2] - 1.0) > 0.05:
        return None
    trk._icp_last[obj] = (last[0], last[1], last[2], last[3] + 1)
    return last[0]


def pose_stack(trk: MultiObjectTracker, poses: dict[str, Pose]) -> tuple[np.ndarray, np.ndarray]:
    """The parts' estimates ``poses`` stacked as :func:`intersects_others` reads them: rotations (1, K, 3, 3) and
    positions (1, K, 3), camera frame (m)."""
    k = len(trk.parts)
    R = np.empty((1, k, 3, 3))
    t = np.empty((1, k, 3))
    for i, n in enumerate(trk.names):
        R[0, i] = poses[n].R
        t[0, i] = poses[n].t
    return R, t


def intersects_others(trk: MultiObjectTracker, obj: int, pose: Pose, poses: dict[str, Pose],
                      stack: tuple[np.ndarray, np.ndarray] | None = None) -> bool:
    """Would part ``obj`` at ``pose`` interpenetrate another part's estimate (beyond the contact tolerance)?
    ``stack``: :func:`pose_stack` of ``poses`` when already made (part ``obj``'s row is replaced during the test and
    put back)."""
    k = len(trk.parts)
    if k < 2:
        return False
    R, t = pose_stack(trk, poses) if stack is None else stack
    keep_R, keep_t = R[0, obj].copy(), t[0, obj].copy()
    R[0, obj] = pose.R
    t[0, obj] = pose.t
    pairs = np.empty((k - 1, 2), np.int64)
    pairs[:, 0] = obj
    pairs[:, 1] = [o for o in range(k) if o != obj]
    try:
        return bool(intersection_flags(R, t, trk.center, trk.half, pairs, trk.config.contact_tolerance)[0])
    finally:
        R[0, obj], t[0, obj] = keep_R, keep_t
