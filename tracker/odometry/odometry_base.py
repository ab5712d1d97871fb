"""What every odometry method shares: input checks, the constant-velocity fallback for frames that cannot be
measured (``skip``) and the latest pose."""

from __future__ import annotations

import time

import numpy as np

from tracker.frame import Frame
from tracker.geometry.camera import Intrinsics
from tracker.geometry.pose import Pose
from tracker.odometry.motion_prior import ConstantVelocity
from tracker.odometry.odometry_result import OdometryResult


class OdometryBase:
    """Base of :class:`CameraOdometry` and :class:`FastSlamOdometry`: ``intrinsics``, a constant-velocity model of
    the camera (``_motion``) and the latest pose (``pose``, camera → world)."""

    def __init__(self, intrinsics: Intrinsics) -> None:
        self.intrinsics = intrinsics
        self._motion = ConstantVelocity()
        self._pose = Pose()

    @property
    def pose(self) -> Pose:
        """The latest camera pose in the world frame."""
        return self._pose

    def skip(self, timestamp: float, reason: str) -> OdometryResult:
        """A frame that could not be read: the constant-velocity pose at ``timestamp``, flagged with ``reason``."""
        t0 = time.perf_counter()
        T = self._motion.predict(timestamp)
        self._motion.update(timestamp, T, measured=False)
        self._pose = Pose.from_matrix(T)
        return OdometryResult(self._pose, False, 0, 1e3 * (time.perf_counter() - t0), float(timestamp), message=reason)

    def _check(self, frame: Frame, mask: np.ndarray | None) -> str:
        """ValueError for a frame or mask of the wrong size; a message when the frame has no depth, else ''."""
        if (frame.intrinsics.width, frame.intrinsics.height) != (self.intrinsics.width, self.intrinsics.height):
            raise ValueError(f"odometry: frame {frame.index} is {frame.intrinsics.width}x{frame.intrinsics.height}, "
                             f"the odometry was set up for {self.intrinsics.width}x{self.intrinsics.height}")
        if mask is not None and np.shape(mask) != frame.color.shape[:2]:
            raise ValueError(f"odometry: mask shape {np.shape(mask)} differs from the image {frame.color.shape[:2]}")
        if not frame.has_depth:
            return f"frame {frame.index}: no depth — pose extrapolated at constant velocity"
        return ""
