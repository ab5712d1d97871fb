"""Camera ego-motion: where the camera is relative to the static scene (issue 15, seed 001).

* :class:`~tracker.odometry.camera_odometry.CameraOdometry` — the default: dense frame-to-keyframe RGB-D odometry
  (point-to-plane + photometric Gauss-Newton on an image pyramid).
* :class:`~tracker.odometry.fastslam_odometry.FastSlamOdometry` — the seed's method: AKAZE features with depth as
  3-D landmarks in a FastSLAM 1.0 particle filter (spec ``camera-localisation.md``).

Both take ``step(frame, mask=None)`` and return an :class:`~tracker.odometry.odometry_result.OdometryResult` whose
pose is the camera's pose in the world frame = the first frame's camera frame. :func:`make_odometry` builds one by
method name.

Use in the tracker (issue 15 item 3): :class:`~tracker.odometry.ego_motion.EgoMotion` runs the odometry as a stage
before the particle filter's step (mask of hands, arms, moving parts and foreground; the camera motion to apply with
:func:`tracker.filter.camera_motion.apply_camera_motion`; the table plane propagated). ``AssemblyPipeline(...,
odometry="default")``, ``track --odometry default`` and ``serve --odometry default`` switch it on.
"""

from __future__ import annotations

from tracker.geometry.camera import Intrinsics
from tracker.odometry.camera_odometry import CameraOdometry
from tracker.odometry.odometry_config import OdometryConfig
from tracker.odometry.odometry_result import OdometryResult

METHODS = ("default", "fastslam")
"""Method names of :func:`make_odometry` (``default`` = the dense RGB-D odometry)."""


def make_odometry(method: str, intrinsics: Intrinsics, seed: int = 0, config: OdometryConfig | None = None):
    """An odometry of ``method`` (one of :data:`METHODS`) for images with these intrinsics; ``config``: the dense
    odometry's settings (default :class:`OdometryConfig`)."""
    if method == "default":
        return CameraOdometry(intrinsics, config or OdometryConfig(), seed=seed)
    if method == "fastslam":
        from tracker.odometry.fastslam_odometry import FastSlamOdometry

        return FastSlamOdometry(intrinsics, seed=seed)
    raise ValueError(f"odometry method must be one of {', '.join(METHODS)}, got {method!r}")


__all__ = ["METHODS", "CameraOdometry", "OdometryConfig", "OdometryResult", "make_odometry"]
