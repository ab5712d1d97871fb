"""Scene-motion stage (not in the seed; an addition of the tracker): hidden resting parts follow the camera's motion
as the visible resting parts show it.

The filter works in the camera frame, so when the camera moves (hand-held, a bumped tripod) a part that stays put
in the world moves in the camera frame. Visible parts are pulled along by their depth; a part hidden under a hand
is held by the rest prior at its last camera-frame position and drifts from the truth by the camera's motion. The
parts that are seen well and refined (dense-depth refinement healthy, not carried, not moving with a blob) are
landmarks: if they stay put in the world, each one's pose change between two frames, ``D_i = P_i(now) P_i(prev)⁻¹``
(camera frame), is the same rigid motion of the camera. A consensus motion is taken from them (the candidate that
the most landmarks agree with within ``scene_motion_tolerance``, averaged over those; at least
``scene_motion_min_anchors`` must agree, and more than half of them, so that a part pushed by a hand is outvoted),
and applied to the parts that no landmark is and that the depth did not place this frame (hidden, or seen in colour
with no depth on them, as in a hand's projector shadow), unless carried or moving with their blob: their particles,
estimate and rest anchor.
Motions smaller than ``scene_motion_deadband`` at the part are not applied (refinement noise would make a random
walk of a hidden part under a still camera).

Camera frame, metres, radians. With camera odometry on (:mod:`tracker.odometry.ego_motion`) the landmarks' pose
changes are already near zero and nothing moves here.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numba as nb
import numpy as np

from tracker.filter.camera_motion import move_part
from tracker.filter.motion_model import mean_rotation, rotvec_to_matrix
from tracker.refine.part_refiner import rotation_angle

if TYPE_CHECKING:
    from tracker.filter.particle_filter import MultiObjectTracker, TrackerState


def landmarks(trk: MultiObjectTracker) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Parts that can serve as landmarks this frame: index → (R, t) of the refined estimate."""
    cfg = trk.config
    out = {}
    if trk._refiner is None:
        return out
    carried = trk._carry.carried
    for i, name in enumerate(trk.names):
        res = trk._refiner.last[i]
        if (res is None or not res.healthy or res.position_only or carried[i] or trk._blob_moved[i]
                or trk.visibility[i] < cfg.visible_fraction_full):
            continue
        est = trk.estimates[name]
        out[i] = (est.R.copy(), est.t.copy())
    return out


def consensus_motion(pairs: list[tuple[np.ndarray, np.ndarray, np.ndarray]], tolerance: float,
                     min_agree: int, spread: float = 0.0) -> tuple[np.ndarray, np.ndarray] | None:
    """The rigid motion ``(Rd, td)`` (x_now = Rd x_prev + td) most landmarks agree with, or None.

    ``pairs``: per landmark (Rd_i, td_i, c_i): its own motion and its centre in the previous frame (m). A landmark
    agrees with a candidate when the candidate moves its centre within ``tolerance`` m of where the landmark's own
    motion moves it and the rotations differ by less than ``tolerance`` / 0.05 rad (about 3.4° at 3 mm).

    The agreeing landmarks' motion: with ``spread`` 0, the mean of their rotations and the translation that moves
    their centres where their own motions do, on average. With ``spread`` > 0 (m), the least-squares rigid motion
    (:func:`fit_rigid`, with a weak prior of no turn) of six points per landmark, its centre ± ``spread`` along
    each camera axis, each moved by the landmark's own motion: a landmark's own turn then counts with its size's
    lever arm, the landmarks' spread across the table with theirs, so that the refinement's turn jitter of a small
    part is not carried to a part 15 cm away as millimetres of false motion."""
    if len(pairs) < min_agree:
        return None
    best: list[int] = []
    table = agreement(np.array([q[0] for q in pairs], np.float64), np.array([q[1] for q in pairs], np.float64),
                      np.array([q[2] for q in pairs], np.float64), float(tolerance))
    for a in range(len(pairs)):
        agree = np.flatnonzero(table[a]).tolist()
        if len(agree) > len(best):
            best = agree
    if len(best) < min_agree or 2 * len(best) <= len(pairs):
        return None
    if spread > 0:
        offsets = np.vstack([np.eye(3), -np.eye(3)]) * spread
        before = np.vstack([pairs[j][2] + offsets for j in best])
        after = np.vstack([(pairs[j][2] + offsets) @ pairs[j][0].T + pairs[j][1] for j in best])
        return fit_rigid(before, after)
    Rm = mean_rotation(np.array([pairs[j][0] for j in best]), np.ones(len(best)))
    # translation: the one that moves the agreeing centres where their own motions move them, on average
    cs = np.array([pairs[j][2] for j in best])
    moved = np.array([pairs[j][0] @ pairs[j][2] + pairs[j][1] for j in best])
    tm = (moved - cs @ Rm.T).mean(axis=0)
    return Rm, tm


TURN_PRIOR_LEVER = 0.02
"""Metres: the scene-motion fit's prior of no camera turn weighs as much as one point this far from the landmarks'
centroid saying so (:func:`fit_rigid`)."""


def fit_rigid(a: np.ndarray, b: np.ndarray, iterations: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Rigid motion ``(R, t)`` with ``b ≈ R a + t`` for point sets (N, 3), metres: least squares over the points'
    displacements with a weak prior of no turn (:data:`TURN_PRIOR_LEVER`), Gauss-Newton on the rotation vector
    about the points' centroid. A turn the points do not constrain (about the line through two landmarks) stays
    near zero instead of taking the landmarks' own turn jitter."""
    ca = a.mean(axis=0)
    rel = a - ca
    R = np.eye(3)
    tc = b.mean(axis=0) - ca
    for _ in range(iterations):
        q = rel @ R.T
        r = (b - ca - q).reshape(-1)  # residual with the translation left free
        J = np.zeros((a.shape[0], 3, 6))
        J[:, 0, 1], J[:, 0, 2] = q[:, 2], -q[:, 1]  # d(w × q) = -[q]× dw
        J[:, 1, 0], J[:, 1, 2] = -q[:, 2], q[:, 0]
        J[:, 2, 0], J[:, 2, 1] = q[:, 1], -q[:, 0]
        J[:, :, 3:] = np.eye(3)
        J = J.reshape(-1, 6)
        A = J.T @ J
        A[:3, :3] += np.eye(3) * TURN_PRIOR_LEVER**2
        x = np.linalg.solve(A, J.T @ r)
        R = rotvec_to_matrix(x[:3])[0] @ R
        tc = x[3:]
    return R, ca + tc - R @ ca


def agrees(Ra: np.ndarray, ta: np.ndarray, Rb: np.ndarray, tb: np.ndarray, c: np.ndarray, tolerance: float) -> bool:
    """Do the rigid transforms ``(Ra, ta)`` and ``(Rb, tb)`` agree at the point ``c`` (m): they take it within
    ``tolerance`` m of each other and differ by less than ``tolerance`` / 0.05 rad in rotation (about 3.4° at 3 mm)?"""
    return bool(np.linalg.norm((Ra @ c + ta) - (Rb @ c + tb)) < tolerance
                and rotation_angle(Ra.T @ Rb) < tolerance / 0.05)


@nb.njit(cache=True)
def agreement(Rs: np.ndarray, ts: np.ndarray, cs: np.ndarray, tolerance: float) -> np.ndarray:
    """:func:`agrees` of every candidate with every landmark: ``out[a, j]`` = do the motions ``(Rs[a], ts[a])`` and
    ``(Rs[j], ts[j])`` agree at ``cs[j]`` (L × L bool, motions (L, 3, 3) and (L, 3), centres (L, 3), metres). The
    same tests in plain loops (sums in index order, where numpy's BLAS calls may round the last bit differently:
    the same answers but for a distance or angle within an ulp of its bound)."""
    m = Rs.shape[0]
    out = np.zeros((m, m), np.bool_)
    max_angle = tolerance / 0.05
    for a in range(m):
        for j in range(m):
            d2 = 0.0
            for r in range(3):
                xa = Rs[a, r, 0] * cs[j, 0] + Rs[a, r, 1] * cs[j, 1] + Rs[a, r, 2] * cs[j, 2] + ts[a, r]
                xj = Rs[j, r, 0] * cs[j, 0] + Rs[j, r, 1] * cs[j, 1] + Rs[j, r, 2] * cs[j, 2] + ts[j, r]
                d2 += (xa - xj) * (xa - xj)
            if not math.sqrt(d2) < tolerance:
                continue
            tr = 0.0  # trace(Ra^T Rj)
            for r in range(3):
                tr += Rs[a, 0, r] * Rs[j, 0, r] + Rs[a, 1, r] * Rs[j, 1, r] + Rs[a, 2, r] * Rs[j, 2, r]
            cos = min(max((tr - 1.0) / 2.0, -1.0), 1.0)
            out[a, j] = math.acos(cos) < max_angle
    return out


def placed_by_depth(trk: MultiObjectTracker, obj: int) -> bool:
    """Did this frame's dense-depth refinement place part ``obj`` (healthy)? A part seen in colour whose depth is
    missing (the hand's projector shadow) or hidden is not placed, and follows the scene."""
    res = trk._refiner.last[obj] if trk._refiner is not None else None
    return res is not None and res.healthy


def unplaced_parts(trk: MultiObjectTracker, landmarks) -> list[int]:
    """Indices of the parts this frame's depth did not place: not a landmark (``landmarks``: indices), not carried,
    not moving with their blob, no healthy dense refinement, not placed by their colour outline on the table
    (:mod:`tracker.refine.table_silhouette`). They follow the camera's motion as the scene shows it
    (:func:`follow_scene`) or as the fused odometry corrects it
    (:func:`tracker.filter.camera_motion.follow_correction`)."""
    carried = trk._carry.carried
    return [i for i in range(len(trk.names))
            if not (i in landmarks or carried[i] or trk._blob_moved[i] or placed_by_depth(trk, i)
                    or trk.silhouette_placed[i])]


def follow_scene(trk: MultiObjectTracker, state: TrackerState) -> None:
    """Apply the landmarks' consensus motion since the previous frame to the parts the depth did not place
    (module docstring); with ``scene_motion_keyframe``, a part unplaced since an earlier frame is moved by the motion
    since that frame instead (:func:`follow_from_keyframes`)."""
    cfg = trk.config
    now = landmarks(trk)
    prev, trk._landmarks = trk._landmarks, now
    if not cfg.scene_motion or not prev:
        trk._scene_keyframes = {}
        return
    unplaced = unplaced_parts(trk, now)
    if cfg.scene_motion_keyframe:
        unplaced = follow_from_keyframes(trk, state, now, unplaced)
    motion = consensus_motion(landmark_motions(trk, prev, now), cfg.scene_motion_tolerance,
                              cfg.scene_motion_min_anchors, cfg.scene_motion_spread)
    if cfg.carry_motion_scene and motion is not None:
        trk._carry.move_history(*motion)
    for i in unplaced:
        if motion is not None:
            move_by(trk, state, i, *motion)
        if cfg.scene_motion_keyframe:  # this frame is the part's keyframe from now on
            est = trk.estimates[trk.names[i]]
            trk._scene_keyframes[i] = (now, est.R.copy(), est.t.copy())


def landmark_motions(trk: MultiObjectTracker, before: dict, now: dict) -> list:
    """Each landmark's own rigid motion from ``before`` to ``now`` (index → (R, t)) with its centre before, for
    :func:`consensus_motion`; landmarks in both only."""
    pairs = []
    for i, (R1, t1) in now.items():
        if i not in before:
            continue
        R0, t0 = before[i]
        Rd = R1 @ R0.T
        pairs.append((Rd, t1 - Rd @ t0, R0 @ trk.center[i] + t0))
    return pairs


def move_by(trk: MultiObjectTracker, state: TrackerState, i: int, Rd: np.ndarray, td: np.ndarray) -> None:
    """Move part ``i`` by the camera-frame motion ``x ↦ Rd x + td`` unless that moves its centre by less than
    ``scene_motion_deadband``."""
    name = trk.names[i]
    est = trk.estimates[name]
    c = est.R @ trk.center[i] + est.t
    if np.linalg.norm(Rd @ c + td - c) < trk.config.scene_motion_deadband:
        return
    move_part(trk, i, Rd, td)
    state.poses[name] = trk.estimates[name]
    state.particles[name] = trk.p[:, i].astype(np.float32)


def follow_from_keyframes(trk: MultiObjectTracker, state: TrackerState, now: dict, unplaced: list[int]) -> list[int]:
    """``scene_motion_keyframe``: a part unplaced since an earlier frame (its keyframe: the landmarks' poses and its
    own pose then) is put where the landmarks' consensus motion since that frame takes its keyframe pose. Chaining
    frame-to-frame motions adds up the landmarks' refinement noise as a random walk over a long occlusion; this does
    not. Keyframes of parts placed again are dropped. Returns the unplaced parts left to move frame to frame: those
    without a keyframe or whose keyframe's landmarks no longer agree on a motion (they get a new keyframe)."""
    cfg = trk.config
    keys = {i: k for i, k in trk._scene_keyframes.items() if i in unplaced}
    trk._scene_keyframes = keys
    rest = []
    for i in unplaced:
        key = keys.get(i)
        motion = None
        if key is not None:
            motion = consensus_motion(landmark_motions(trk, key[0], now), cfg.scene_motion_tolerance,
                                      cfg.scene_motion_min_anchors, cfg.scene_motion_spread)
        if motion is None:
            rest.append(i)
            continue
        Rm, tm = motion
        est = trk.estimates[trk.names[i]]
        R_target, t_target = Rm @ key[1], Rm @ key[2] + tm
        Rd = R_target @ est.R.T
        move_by(trk, state, i, Rd, t_target - Rd @ est.t)
    return rest
