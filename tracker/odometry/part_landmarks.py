"""Camera pose from the tracked parts that stay put (an addition to issue 15's odometry; not in the seed).

The parts on the table are landmarks the tracker already measures to a fraction of a millimetre: a part that is
seen well (dense-depth refinement healthy, not carried, not moving with its blob; see
:func:`tracker.filter.scene_motion.landmarks`) gives its pose ``P`` in the camera frame, and once its pose ``W`` in
the world frame is known, the camera's pose follows from ``T_cw = P W⁻¹`` (world → camera). A hand that moves a part
makes that part disagree with the others, so the camera pose is the consensus of the landmarks
(:func:`tracker.filter.scene_motion.consensus_motion`: the candidate most landmarks agree with), refined by one rigid
fit (Kabsch) of the agreeing landmarks' corner points, world against camera frame: the parts' spread over the table
fixes the camera's rotation far better than any one part's orientation.

World frame = the camera frame of the first call; every part seen then is a landmark at its first pose. A landmark
whose implied world pose leaves its stored one by more than ``tolerance`` (it was moved) is dropped; a part whose
world pose stays the same for ``adopt_frames`` calls in a row (it rests again, or is newly seen) becomes a landmark
at that pose. Without any agreeing landmark the last camera pose is kept. Camera poses are ``pose_world_camera``
(maps camera-frame points to the world), metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tracker.filter.scene_motion import agrees, consensus_motion
from tracker.geometry.pose import Pose
from tracker.odometry.akaze_features import kabsch


@dataclass
class Pending:
    """A part on its way to becoming a landmark: its world pose (part → world) and for how many calls in a row it
    stayed the same."""

    pose: Pose
    count: int


def maintain_landmarks(world: dict[str, Pose], pending: dict[str, Pending], pose_world_camera: Pose,
                       observed: dict[str, Pose], centres: dict[str, np.ndarray], tolerance: float,
                       adopt_frames: int, keep: frozenset[str] = frozenset()) -> None:
    """Drop the landmarks in ``world`` whose world pose implied by this frame's ``observed`` part → camera pose
    (through ``pose_world_camera``) no longer agrees with theirs (:func:`~tracker.filter.scene_motion.agrees` at the
    part's body-frame ``centres``; parts in ``keep`` stay), and adopt the parts whose implied world pose stayed the
    same for ``adopt_frames`` calls. ``world`` and ``pending`` are updated in place."""
    for name, P in observed.items():
        implied = pose_world_camera @ P
        c = centres[name]
        W = world.get(name)
        if W is not None:
            if name not in keep and not agrees(W.R, W.t, implied.R, implied.t, c, tolerance):
                del world[name]
                pending[name] = Pending(implied, 1)
            continue
        p = pending.get(name)
        if p is not None and agrees(p.pose.R, p.pose.t, implied.R, implied.t, c, tolerance):
            p.count += 1
            p.pose = implied
            if p.count >= adopt_frames:
                world[name] = implied
                del pending[name]
        else:
            pending[name] = Pending(implied, 1)


@dataclass
class PartLandmarkOdometry:
    """See the module docstring. ``tolerance`` (m): agreement of two poses at the part's centre (and in rotation,
    ``tolerance / 0.05`` rad); ``adopt_frames``: calls a part's world pose must stay the same to become a landmark."""

    tolerance: float = 0.003
    adopt_frames: int = 5
    world: dict[str, Pose] = field(default_factory=dict)
    pending: dict[str, Pending] = field(default_factory=dict)
    pose_world_camera: Pose | None = None
    used: int = 0
    """Landmarks that agreed on the last pose (0: the previous pose was kept)."""

    def update(self, observed: dict[str, Pose], points: dict[str, np.ndarray]) -> Pose:
        """One frame: ``observed`` part → camera poses of the parts usable as landmarks now, ``points`` each part's
        corner points (M, 3) in its body frame (m; their mean is its centre). Returns the camera's pose in the
        world."""
        centres = {n: np.asarray(p, np.float64).mean(axis=0) for n, p in points.items()}
        if self.pose_world_camera is None:
            self.pose_world_camera = Pose()
            self.world = dict(observed)
            self.used = len(observed)
            return self.pose_world_camera
        pairs, names = [], []
        for name, P in observed.items():
            W = self.world.get(name)
            if W is None:
                continue
            R = P.R @ W.R.T
            pairs.append((R, P.t - R @ W.t, W.R @ centres[name] + W.t))
            names.append(name)
        motion = consensus_motion(pairs, self.tolerance, min(2, len(pairs))) if pairs else None
        if motion is None:
            self.used = 0
        else:
            # the landmarks that agree with the consensus, fitted together on their corner points: one part's
            # rotation error (~0.5°) would move the camera by its lever arm (~5 mm at 0.6 m); the parts' spread
            # across the table constrains the rotation far better
            R_cw, t_cw = motion
            agree = [n for n, (R, t, c) in zip(names, pairs, strict=True)
                     if np.linalg.norm((R_cw @ c + t_cw) - (R @ c + t)) < self.tolerance]
            if agree:  # (the averaged consensus may agree with none of them: then it stands as it is)
                world_pts = np.vstack([self.world[n].transform_points(points[n]) for n in agree])
                camera_pts = np.vstack([observed[n].transform_points(points[n]) for n in agree])
                R_cw, t_cw = kabsch(world_pts, camera_pts)
            self.pose_world_camera = Pose.from_rt(R_cw, t_cw).inverse()
            self.used = max(len(agree), 1)
        maintain_landmarks(self.world, self.pending, self.pose_world_camera, observed, centres, self.tolerance,
                           self.adopt_frames)
        return self.pose_world_camera
