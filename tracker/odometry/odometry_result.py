"""What an odometry step returns (:class:`OdometryResult`)."""

from __future__ import annotations

from dataclasses import dataclass

from tracker.geometry.pose import Pose


@dataclass(frozen=True)
class OdometryResult:
    """The camera's estimated pose after one frame.

    * ``pose_world_camera``: the camera's pose in the world frame (camera → world; the world frame is the first
      frame's camera frame: x right, y down, z forward; metres, Hamilton quaternion).
    * ``ok``: False when the pose is not measured but extrapolated (constant velocity) — no depth, a corrupt frame,
      a failed or implausible alignment; ``message`` then says why.
    * ``inliers``: correspondences that support the pose (0 when not measured).
    * ``ms``: wall time of the step, milliseconds.
    * ``keyframe``: the frame became a keyframe.
    * ``timestamp``: the frame's time, seconds.
    """

    pose_world_camera: Pose
    ok: bool
    inliers: int
    ms: float
    timestamp: float
    keyframe: bool = False
    message: str = ""
