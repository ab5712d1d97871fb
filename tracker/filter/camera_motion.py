"""Move the tracker's camera-frame state by the camera's own motion (issue 15: parts kept in the world frame).

The particle filter works in the camera frame. When the camera moves by ``T_new_old`` (4×4, maps points of the old
camera frame to the new one: ``X_new = R X_old + t``, metres), a part that stays put in the world moves by
``T_new_old`` in the camera frame. :func:`apply_camera_motion` applies that change of frame to everything the
tracker keeps in camera coordinates, before its next step, so that the prediction of a static part is where the
part now appears and the filter only has to explain the parts' own motion:

* particle positions ``p`` and rotations ``R`` (``R_new = R_d R``);
* particle velocities (translation and rotation-vector parts are camera-frame vectors: rotated by ``R_d``);
* the estimates, the rest-prior anchors, the last dense-refinement result that may be reused, the hand-carry
  memory (past positions, hand points, last hand step and turn) and scene motion's landmark poses of the last frame;
* the constant-velocity model's memory (the last frame's estimates and the smoothed velocities), so that a velocity
  measured next frame is the part's own motion, not the camera's applied a second time;
* the hand carry's last depth image is dropped (a camera-frame image cannot be moved; a carry starting on this frame
  takes this frame's hand points, as it did before the carry registered from the last frame).

The last frame's blob centroids (blob follow, and the hand carry's check that a carried part's blob follows the
hand) are moved by the image motion the camera's motion gives each part's centre (otherwise the camera's share of a
blob's shift would be counted twice). Other pixel-indexed state (occlusion posteriors) is left as it is: it is
renewed from the image every frame.

With the fused odometry, the resting parts correct the camera's pose after the tracker's step; the parts this frame's
depth did not place (hidden, resting) are moved by that correction (:func:`follow_correction`) instead of by scene
motion's frame-to-frame consensus (:func:`hand_hidden_parts_to_the_odometry`), so that they do not keep the dense
odometry's drift.
"""

from __future__ import annotations

import numpy as np

from tracker.filter.motion_model import rotate_left
from tracker.geometry.pose import Pose


def apply_camera_motion(trk, T_new_old: np.ndarray) -> None:
    """Express ``trk`` (a :class:`~tracker.filter.particle_filter.MultiObjectTracker` after ``initialize``) in the
    new camera frame; ``T_new_old``: 4×4 rigid transform from the old camera frame to the new one."""
    T = np.asarray(T_new_old, np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"camera motion must be a finite 4x4 transform, got shape {T.shape}")
    Rd, td = T[:3, :3], T[:3, 3]
    if not getattr(trk, "_initialized", False):
        return
    shifts = _image_shifts(trk, Rd, td)
    trk._follow_blobs = _shifted(getattr(trk, "_follow_blobs", None), shifts)
    trk._last_centers = {i: np.asarray(c, np.float64) + shifts.get(i, 0.0)
                         for i, c in getattr(trk, "_last_centers", {}).items()}
    trk.p = trk.p @ Rd.T + td
    Rc = np.ascontiguousarray(Rd)  # rotate_left: np.einsum's values at a seventh of its time (225 x 7 particles)
    trk.R = rotate_left(Rc, trk.R.reshape(-1, 3, 3)).reshape(trk.R.shape)
    v = trk.v.copy()
    v[..., :3] = trk.v[..., :3] @ Rd.T
    v[..., 3:] = trk.v[..., 3:] @ Rd.T
    trk.v = v
    D = Pose.from_matrix(T)
    trk.estimates = {name: D @ pose for name, pose in trk.estimates.items()}
    if getattr(trk, "_prev_poses", None) is not None:
        trk._prev_poses = {name: D @ pose for name, pose in trk._prev_poses.items()}
    if hasattr(trk, "_est_vel"):
        vel = trk._est_vel.copy()
        vel[:, :3] = trk._est_vel[:, :3] @ Rd.T
        vel[:, 3:] = trk._est_vel[:, 3:] @ Rd.T
        trk._est_vel = vel
    trk._rest_t = trk._rest_t @ Rd.T + td
    trk._rest_R = rotate_left(Rc, trk._rest_R)
    trk._icp_last = [None if last is None else (D @ last[0], *last[1:]) for last in trk._icp_last]
    # scene motion's landmark poses of the last frame: unmoved, the camera's motion would show up as the landmarks'
    # consensus motion and be applied to the hidden parts a second time
    trk._landmarks = {i: (Rd @ R, Rd @ t + td) for i, (R, t) in getattr(trk, "_landmarks", {}).items()}
    carry = getattr(trk, "_carry", None)
    if carry is not None:
        carry.move_with_camera(Rd, td)


def _image_shifts(trk, Rd: np.ndarray, td: np.ndarray) -> dict[int, np.ndarray]:
    """Per part (index), the image shift (pixels, ``[du, dv]``) the camera's motion gives its estimated centre;
    parts behind or too near the camera get none."""
    out: dict[int, np.ndarray] = {}
    for i, name in enumerate(trk.names):
        est = trk.estimates.get(name)
        if est is None:
            continue
        c = est.R @ trk.center[i] + est.t
        c_new = Rd @ c + td
        if c[2] <= 0.05 or c_new[2] <= 0.05:
            continue
        uv = trk.intrinsics.project(np.stack([c, c_new]))
        out[i] = uv[1] - uv[0]
    return out


def _shifted(blobs, shifts: dict[int, np.ndarray]):
    """The last frame's blobs (blob follow, :mod:`tracker.filter.blob_follow`: ``(centroid px, area)``, with
    ``blob_follow_overlap`` also ``outline``, or None per part) with each centroid (and outline, to the nearest pixel)
    moved by its part's image shift, so that a blob's shift to this frame is the part's own motion (the camera's
    share is applied to the part already here; unmoved, it would be counted twice)."""
    if not blobs:
        return blobs
    out = []
    for i, blob in enumerate(blobs):
        if blob is not None and i in shifts:
            d = shifts[i]
            moved = (np.asarray(blob[0], np.float64) + d, blob[1])
            if len(blob) > 2 and blob[2] is not None:
                x0, y0, mask = blob[2]
                moved += ((x0 + int(round(float(d[0]))), y0 + int(round(float(d[1]))), mask),)
            blob = moved
        out.append(blob)
    return out


def move_part(trk, obj: int, R: np.ndarray, t: np.ndarray, anchor: bool = True) -> None:
    """Move part ``obj`` of ``trk`` rigidly in the camera frame, x ↦ ``R`` x + ``t`` (metres): its particles, estimate
    and (with ``anchor``) rest anchor; its velocities are zeroed. (A part carried by a hand, moved with its blob, or
    kept in place while the camera moves.)"""
    trk.p[:, obj] = trk.p[:, obj] @ R.T + t
    trk.R[:, obj] = rotate_left(np.ascontiguousarray(R, np.float64), trk.R[:, obj])  # np.einsum's values
    trk.v[:, obj] = 0.0
    if anchor:
        trk._rest_t[obj] = R @ trk._rest_t[obj] + t
        trk._rest_R[obj] = R @ trk._rest_R[obj]
    est = trk.estimates[trk.names[obj]]
    trk.estimates[trk.names[obj]] = Pose.from_rt(R @ est.R, R @ est.t + t)


def follow_correction(trk, T_new_old: np.ndarray, poses: dict | None = None) -> list[str]:
    """Move the parts of ``trk`` that this frame's depth did not place — not a landmark, not carried, not moving with
    their blob, no healthy dense refinement: hidden resting parts — by ``T_new_old`` (4×4, the camera-frame
    correction of :meth:`tracker.odometry.ego_motion.EgoMotion.observe`). ``poses`` (name → pose), if given, gets
    their new estimates. Returns the names of the parts moved. The parts placed by the depth are measured in the
    true camera frame already."""
    from tracker.filter.scene_motion import unplaced_parts

    T = np.asarray(T_new_old, np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"camera correction must be a finite 4x4 transform, got shape {T.shape}")
    moved = []
    for i in unplaced_parts(trk, trk._landmarks):
        name = trk.names[i]
        move_part(trk, i, T[:3, :3], T[:3, 3])
        moved.append(name)
        if poses is not None:
            poses[name] = trk.estimates[name]
    return moved


def hand_hidden_parts_to_the_odometry(trk, ego) -> bool:
    """With the fused odometry (``ego``: :class:`~tracker.odometry.ego_motion.EgoMotion`), on a frame where it will
    correct the camera after the tracker's step (``ego.correction_pending``), the hidden parts follow that correction
    (:func:`follow_correction`), not scene motion's frame-to-frame consensus of the landmarks (both measure the same
    error of the applied camera motion: applying both would count it twice). Called before the tracker's step: scene
    motion then has no last-frame landmarks to compare with (it still records this frame's, which the odometry
    reads). While the odometry idles (a camera at rest) nothing is handed over: scene motion works as with odometry
    off. Returns whether the hidden parts were handed over."""
    if not ego.correction_pending:
        return False
    trk._landmarks = {}
    return True
