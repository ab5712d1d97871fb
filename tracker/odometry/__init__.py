"""Camera ego-motion: where the camera is relative to the static scene (issue 15, seed 001).

* :class:`~tracker.odometry.camera_odometry.CameraOdometry` — the default: dense frame-to-keyframe RGB-D odometry
  (point-to-plane + photometric Gauss-Newton on an image pyramid).
* :class:`~tracker.odometry.fastslam_odometry.FastSlamOdometry` — the seed's method: AKAZE features with depth as
  3-D landmarks in a FastSLAM 1.0 particle filter (spec ``camera-localisation.md``).

Both take ``step(frame, mask=None)`` and return an :class:`~tracker.odometry.odometry_result.OdometryResult` whose
pose is the camera's pose in the world frame = the first frame's camera frame. :func:`make_odometry` builds one by
method name.

Use in the tracker (issue 15 item 3; the pipeline owns the wiring)::

    odo = CameraOdometry(intrinsics)                       # once per source; odo.reset() when the source restarts
    mask = exclusion_mask(frame.color.shape[:2], hand_box, part_masks_of_moving_parts)   # True = exclude
    res = odo.step(frame, mask)                            # ~15–25 ms CPU per 640×480 frame
    T_wc = res.pose_world_camera                           # camera → world (world = first camera frame)
    # parts kept in the world frame: T_world_obj = T_wc @ T_cam_obj; predict each part in the new camera frame as
    # T_cam_obj = T_wc.inverse() @ T_world_obj before the particle filter's step (static parts then stay put);
    # table plane propagated, not re-detected: with table_to_camera_0 from the first detection,
    # table_to_camera = T_wc.inverse() @ T_w_table, where T_w_table = table_to_camera_0 (world = camera 0);
    # res.ok False (no depth, failed alignment): the pose is extrapolated — keep the parts' camera-frame
    # prediction and re-check the table plane.
    # Snapshot.camera_pose = T_wc, Snapshot.camera_pose_ok = res.ok (the viser scene then shows the camera frustum
    # and its path).
"""

from __future__ import annotations

from tracker.geometry.camera import Intrinsics
from tracker.odometry.camera_odometry import CameraOdometry
from tracker.odometry.odometry_config import OdometryConfig
from tracker.odometry.odometry_result import OdometryResult

METHODS = ("default", "fastslam")
"""Method names of :func:`make_odometry` (``default`` = the dense RGB-D odometry)."""


def make_odometry(method: str, intrinsics: Intrinsics, seed: int = 0):
    """An odometry of ``method`` (one of :data:`METHODS`) for images with these intrinsics."""
    if method == "default":
        return CameraOdometry(intrinsics, OdometryConfig(), seed=seed)
    if method == "fastslam":
        from tracker.odometry.fastslam_odometry import FastSlamOdometry

        return FastSlamOdometry(intrinsics, seed=seed)
    raise ValueError(f"odometry method must be one of {', '.join(METHODS)}, got {method!r}")


__all__ = ["METHODS", "CameraOdometry", "OdometryConfig", "OdometryResult", "make_odometry"]
