"""The well-known baseline of the odometry benchmark: OpenCV's own RGB-D odometry (``cv2.Odometry``, OpenCV ≥ 5
main module ``3d``/``ptcloud``; the ``rgbd`` contrib module of OpenCV 4 has the same algorithms), run the way its
samples run it: frame to frame, poses chained.

``kind`` ``"rgb"`` is the photometric (dense direct) odometry, ``"rgbd"`` photometric + ICP, ``"depth"`` ICP only;
OpenCV's default settings (4 pyramid levels, 7/7/7/10 iterations, depth 0–4 m) with the camera matrix set. The
hand mask of the benchmark is passed as the frames' mask (255 = usable). Depth in metres (float32, 0 = missing).
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from tracker.frame import Frame
from tracker.geometry.camera import Intrinsics
from tracker.geometry.pose import Pose
from tracker.odometry.odometry_result import OdometryResult

KINDS = {"rgb": "OdometryType_RGB", "rgbd": "OdometryType_RGB_DEPTH", "depth": "OdometryType_DEPTH"}


class OpenCvOdometry:
    """Frame-to-frame ``cv2.Odometry`` with the benchmark's ``step(frame, mask)`` interface."""

    def __init__(self, intrinsics: Intrinsics, kind: str = "rgb") -> None:
        if not hasattr(cv2, "Odometry"):
            raise RuntimeError("this OpenCV build has no cv2.Odometry (OpenCV >= 5, or the rgbd contrib module)")
        s = cv2.OdometrySettings()
        s.setCameraMatrix(intrinsics.K.astype(np.float32))
        self.kind = kind
        self._odo = cv2.Odometry(getattr(cv2, KINDS[kind]), s, cv2.OdometryAlgoType_COMMON)
        self._prev = None
        self._T = np.eye(4)

    def skip(self, timestamp: float, reason: str) -> OdometryResult:
        """A frame that could not be read: the last pose kept, flagged (the next frame is registered to the last
        one read)."""
        return OdometryResult(Pose.from_matrix(self._T), False, 0, 0.0, float(timestamp), message=reason)

    def step(self, frame: Frame, mask: np.ndarray | None = None) -> OdometryResult:
        t0 = time.perf_counter()
        depth = np.nan_to_num(frame.depth, nan=0.0).astype(np.float32)
        gray = cv2.cvtColor(frame.color, cv2.COLOR_RGB2GRAY)
        m = np.full(gray.shape, 255, np.uint8) if mask is None else np.where(mask, 0, 255).astype(np.uint8)
        cur = cv2.OdometryFrame(depth=depth, image=gray, mask=m)
        ok = True
        if self._prev is not None:
            self._odo.prepareFrames(self._prev, cur)
            ok, Rt = self._odo.compute(self._prev, cur)  # Rt maps previous-camera points into the current camera
            if ok:
                self._T = self._T @ np.linalg.inv(Rt)
        self._prev = cur
        return OdometryResult(Pose.from_matrix(self._T), bool(ok), 0, 1e3 * (time.perf_counter() - t0),
                              float(frame.timestamp))
