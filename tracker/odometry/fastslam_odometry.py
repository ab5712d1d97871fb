"""``FastSlamOdometry``: the seed's localisation as an odometry option — AKAZE features with depth
(:mod:`.akaze_features`) as 3-D landmarks of a FastSLAM 1.0 filter (:mod:`.fastslam`). Same interface as
:class:`~tracker.odometry.camera_odometry.CameraOdometry`: ``step(frame, mask)`` / ``skip(t, reason)`` →
:class:`~tracker.odometry.odometry_result.OdometryResult`, world = the first measured frame's camera frame.

Per frame: detect features outside the mask; match them to the landmark database (one descriptor per landmark,
IDs shared by all particles, as in the thesis); keep the matches consistent with one rigid motion; predict the
particles with the constant-velocity model, update and weight them with the kept matches; add unmatched features
as new landmarks while fewer than ``min_tracked`` landmarks are re-observed; resample when needed.
"""

from __future__ import annotations

import time

import numpy as np

from tracker.frame import Frame
from tracker.geometry.camera import Intrinsics
from tracker.geometry.pose import Pose
from tracker.odometry.akaze_features import AkazeFrontEnd, rigid_inliers
from tracker.odometry.fastslam import FastSlam1, FastSlamConfig
from tracker.odometry.odometry_base import OdometryBase
from tracker.odometry.odometry_result import OdometryResult
from tracker.odometry.se3 import invert, log_se3


class FastSlamOdometry(OdometryBase):
    """AKAZE + FastSLAM 1.0 camera odometry (see the module docstring)."""

    method = "fastslam"

    def __init__(self, intrinsics: Intrinsics, config: FastSlamConfig | None = None, seed: int = 0) -> None:
        super().__init__(intrinsics)
        self.config = config or FastSlamConfig()
        self._rng = np.random.default_rng(seed)
        self.front = AkazeFrontEnd(intrinsics, self.config.max_features)
        self.filter: FastSlam1 | None = None
        self.descriptors = np.zeros((0, 61), np.uint8)

    def step(self, frame: Frame, mask: np.ndarray | None = None) -> OdometryResult:
        """Estimate the camera pose of ``frame``; ``mask`` (H×W bool, True = exclude) marks hands and parts."""
        t0 = time.perf_counter()
        ts = float(frame.timestamp)
        problem = self._check(frame, mask)
        if problem:
            return self.skip(ts, problem)
        cfg = self.config
        feats = self.front.detect(frame.color, frame.depth, mask)
        if self.filter is None:
            self.filter = FastSlam1(self.intrinsics.fx, cfg, self._rng)
            T0 = self._motion.predict(ts)
            self.filter.R[:] = T0[:3, :3]
            self.filter.t[:] = T0[:3, 3]
            keep = np.arange(min(len(feats), cfg.max_new_landmarks))
            self.filter.add_landmarks(feats.points[keep])
            self.descriptors = feats.descriptors[keep].copy()
            self._motion.update(ts, T0, measured=True)
            self._pose = Pose.from_matrix(T0)
            return OdometryResult(self._pose, True, 0, 1e3 * (time.perf_counter() - t0), ts, keyframe=True)

        flt = self.filter
        prev_t, prev_T = self._motion.last or (ts, np.eye(4))
        dt = max(ts - prev_t, 1e-3)
        pred = self._motion.predict(ts)
        twist = log_se3(invert(prev_T) @ pred) / dt if cfg.motion == "constant_velocity" else np.zeros(6)
        flt.predict(twist, dt)
        fi, li = self.front.match(feats, self.descriptors)
        inl = np.zeros(fi.size, bool)
        if fi.size >= 3:
            inl = rigid_inliers(flt.landmark_means()[li], feats.points[fi], cfg.inlier_m, self._rng)
        fi, li = fi[inl], li[inl]
        flt.update(feats.points[fi], li)
        added = False
        if fi.size < cfg.min_tracked and flt.n_landmarks < cfg.max_landmarks:
            new = np.setdiff1d(np.arange(len(feats)), fi)[: cfg.max_new_landmarks]
            if new.size:
                flt.add_landmarks(feats.points[new])
                self.descriptors = np.concatenate([self.descriptors, feats.descriptors[new]])
                added = True
        R, t = flt.estimate()
        flt.resample_if_needed()
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, t
        ok = fi.size >= cfg.min_inliers
        self._motion.update(ts, T, measured=ok)
        self._pose = Pose.from_matrix(T)
        msg = "" if ok else f"frame {frame.index}: only {fi.size} verified feature matches — pose from the motion model"
        return OdometryResult(self._pose, ok, int(fi.size), 1e3 * (time.perf_counter() - t0), ts, keyframe=added,
                              message=msg)
