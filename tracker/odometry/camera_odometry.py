"""``CameraOdometry``: frame-to-keyframe dense RGB-D odometry (the default ego-motion estimator).

Each frame is aligned (:mod:`.dense_alignment`) to the stored keyframe nearest to the constant-velocity
prediction of its pose; when the camera has moved far from every keyframe (or sees too little of the nearest one)
the frame becomes a new keyframe. Because a camera that sways around one place keeps returning to the same
keyframes, the error does not accumulate frame after frame (there is drift only along a chain of keyframes).

World frame = the first frame's camera frame (x right, y down, z forward; metres). Pixels given in ``mask``
(True = exclude: hands, moving parts) are ignored both in the frame and, when it becomes a keyframe, in the
keyframe. Frames that cannot be measured (no depth, corrupt, alignment failed or implausible) get the
constant-velocity pose with ``ok = False`` and a message, so the trajectory has a pose for every frame.
"""

from __future__ import annotations

import time

import numpy as np

from tracker.frame import Frame
from tracker.geometry.camera import Intrinsics
from tracker.geometry.pose import Pose
from tracker.odometry.dense_alignment import align
from tracker.odometry.keyframe import Keyframe, make_keyframe_level
from tracker.odometry.motion_prior import ConstantVelocity
from tracker.odometry.odometry_base import OdometryBase
from tracker.odometry.odometry_config import OdometryConfig
from tracker.odometry.odometry_result import OdometryResult
from tracker.odometry.rgbd_pyramid import build_pyramid
from tracker.odometry.se3 import invert, motion_size


class CameraOdometry(OdometryBase):
    """Dense frame-to-keyframe RGB-D odometry. ``step(frame, mask)`` → :class:`OdometryResult`."""

    method = "dense"

    def __init__(self, intrinsics: Intrinsics, config: OdometryConfig | None = None, seed: int = 0) -> None:
        super().__init__(intrinsics)
        self.config = config or OdometryConfig()
        self._rng = np.random.default_rng(seed)
        self.keyframes: list[Keyframe] = []
        self._active = 0

    def reset(self) -> None:
        """Forget everything: the next frame defines the world frame again."""
        self.keyframes.clear()
        self._motion = ConstantVelocity()
        self._active = 0
        self._pose = Pose()

    def step(self, frame: Frame, mask: np.ndarray | None = None, prior: np.ndarray | None = None) -> OdometryResult:
        """Estimate the camera pose of ``frame`` (colour RGB uint8 + registered depth in metres); ``mask`` (H×W
        bool, True = exclude) marks hands and moving parts. ``prior`` (4×4 camera → world, this odometry's world
        frame), when given, replaces the constant-velocity prediction as the alignment's start and as the reference
        of the plausibility test: a caller that knows the camera's path better (the fused odometry, after a wrong
        registration it rejected) keeps the odometry from extrapolating its own wrong step, and from rejecting every
        later frame against that extrapolation."""
        problem = self._check(frame, mask)
        if problem:
            return self.skip(float(frame.timestamp), problem)
        res = self._step(frame, mask, prior)
        self._pose = res.pose_world_camera
        return res

    def _step(self, frame: Frame, mask: np.ndarray | None, prior: np.ndarray | None = None) -> OdometryResult:
        t0 = time.perf_counter()
        ts = float(frame.timestamp)
        pyr = build_pyramid(frame.color, frame.depth, self.intrinsics, self.config.n_levels, mask,
                            first_level=min(self.config.levels))

        if not self.keyframes:  # the first measured frame fixes the world frame (or continues the prediction)
            T = self._motion.predict(ts)
            self._add_keyframe(pyr, T, frame.index)
            self._motion.update(ts, T, measured=True)
            return OdometryResult(Pose.from_matrix(T), True, 0, 1e3 * (time.perf_counter() - t0), ts, keyframe=True)

        pred = self._motion.predict(ts) if prior is None else np.asarray(prior, np.float64)
        k = self._nearest_keyframe(pred)
        kf = self.keyframes[k]
        cfg = self.config
        res, T, msg = self._checked(kf, pyr, pred, cfg, frame.index)
        last = self._motion.last
        if last is not None and self._far(last[1], pred):  # a fast predicted motion: also from the last pose
            other = self._checked(kf, pyr, last[1], cfg, frame.index)
            if not other[2] and (msg or other[0].inliers > res.inliers):
                res, T, msg = other
        retry = cfg.retry
        if msg and retry is not None:  # again with a coarser start, from the prediction and from the last pose
            tries = [self._checked(kf, pyr, pred, retry, frame.index)]
            if last is not None:
                tries.append(self._checked(kf, pyr, last[1], retry, frame.index))
            good = [t for t in tries if not t[2]]
            if good:  # the plausible result that explains the most of the frame
                res, T, msg = max(good, key=lambda t: t[0].inliers)
        if msg:
            self._motion.update(ts, pred, measured=False)
            return OdometryResult(Pose.from_matrix(pred), False, res.inliers, 1e3 * (time.perf_counter() - t0), ts,
                                  message=msg + " — pose extrapolated at constant velocity")
        self._active = k
        new_kf = False
        kd, kr = motion_size(invert(kf.pose) @ T)
        wanted = kd > cfg.keyframe_distance_m or np.degrees(kr) > cfg.keyframe_angle_deg or \
            res.overlap < cfg.keyframe_min_overlap
        if wanted and mask is not None and res.overlap >= cfg.keyframe_last_overlap and \
                np.count_nonzero(mask) > cfg.keyframe_max_masked * mask.size:
            wanted = False  # a frame mostly hidden by hands is a poor reference: keep the old one while it is seen
        if wanted:
            if self._nearest_keyframe(T) == k:  # no stored keyframe is closer: take this frame
                self._add_keyframe(pyr, T, frame.index)
                new_kf = True
        self._motion.update(ts, T, measured=True)
        return OdometryResult(Pose.from_matrix(T), True, res.inliers, 1e3 * (time.perf_counter() - t0), ts,
                              keyframe=new_kf)

    def _far(self, A: np.ndarray, B: np.ndarray) -> bool:
        """Whether poses ``A`` and ``B`` (4×4) differ by more than ``second_start_m`` or ``second_start_deg``."""
        cfg = self.config
        if cfg.second_start_m <= 0 and cfg.second_start_deg <= 0:
            return False
        d, r = motion_size(invert(A) @ B)
        return (cfg.second_start_m > 0 and d > cfg.second_start_m) or \
            (cfg.second_start_deg > 0 and np.degrees(r) > cfg.second_start_deg)

    def _checked(self, kf: Keyframe, pyr, start: np.ndarray, cfg: OdometryConfig, index: int) -> tuple:
        """Align to ``kf`` from ``start`` (4×4 camera → world: the prediction, or the last measured pose) with
        ``cfg``'s levels; returns ``(alignment, pose 4×4 camera → world, message)``, the message non-empty when the
        result is rejected: too few inliers, or farther than ``max_step_m`` / ``max_step_deg`` from ``start``."""
        res = align(kf, pyr, invert(kf.pose) @ start, cfg)
        T = kf.pose @ res.T_kc
        dt, dr = motion_size(invert(start) @ T)
        msg = ""
        if res.inliers < cfg.min_inliers:
            msg = f"frame {index}: only {res.inliers} inliers (< {cfg.min_inliers})"
        elif dt > cfg.max_step_m or np.degrees(dr) > cfg.max_step_deg:
            msg = f"frame {index}: implausible jump {1e3 * dt:.0f} mm / {np.degrees(dr):.1f}° from its start"
        return res, T, msg

    # ------------------------------------------------------------------------------------------------------
    def _distance(self, A: np.ndarray, B: np.ndarray) -> float:
        """Pose distance normalised by the keyframe thresholds (1 = at the threshold)."""
        d, r = motion_size(invert(A) @ B)
        return max(d / self.config.keyframe_distance_m, np.degrees(r) / self.config.keyframe_angle_deg)

    def _nearest_keyframe(self, T: np.ndarray) -> int:
        dists = [self._distance(kf.pose, T) for kf in self.keyframes]
        best = int(np.argmin(dists))
        # stay with the active keyframe unless another is clearly closer (avoids flicker between two)
        if self._active < len(dists) and dists[self._active] <= 1.0 and dists[self._active] < dists[best] + 0.25:
            return self._active
        return best

    def _add_keyframe(self, pyr, T: np.ndarray, index: int) -> None:
        cfg = self.config
        levels = []
        for lv in range(cfg.n_levels):
            if lv in cfg.levels or lv in cfg.retry_levels:
                levels.append(make_keyframe_level(pyr[lv], cfg.n_photo, cfg.n_geo, cfg.min_gradient, self._rng))
            else:
                levels.append(None)
        self.keyframes.append(Keyframe(levels, np.array(T, dtype=np.float64), int(index)))
        if len(self.keyframes) > cfg.max_keyframes:
            del self.keyframes[1]
        self._active = len(self.keyframes) - 1
