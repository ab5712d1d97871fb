"""Constant-velocity prediction of the camera pose from the last two estimates (used as the alignment's start and
as the pose of frames that cannot be measured). After ``HOLD_AFTER`` unmeasured frames in a row the velocity is
halved on every further one, so a long failure holds the pose instead of extrapolating without bound."""

from __future__ import annotations

import numpy as np

from tracker.odometry.se3 import exp_se3, invert, log_se3

HOLD_AFTER = 2
"""Unmeasured frames in a row extrapolated at the full last velocity; the velocity halves on each further one."""


class ConstantVelocity:
    """Keeps the last two camera poses (4×4 camera → world) with their times and extrapolates the body-frame
    velocity twist (per second) to a new time."""

    def __init__(self) -> None:
        self._last: tuple[float, np.ndarray] | None = None
        self._twist = np.zeros(6)  # body-frame twist per second
        self._missed = 0  # unmeasured updates in a row

    def reset(self, t: float, T: np.ndarray) -> None:
        self._last = (float(t), np.array(T, dtype=np.float64))
        self._twist = np.zeros(6)
        self._missed = 0

    @property
    def started(self) -> bool:
        return self._last is not None

    @property
    def last(self) -> tuple[float, np.ndarray] | None:
        """``(time, pose)`` of the last recorded pose, or None."""
        return self._last

    def predict(self, t: float) -> np.ndarray:
        """Extrapolated pose at time ``t`` seconds (the last pose when fewer than two are known)."""
        if self._last is None:
            return np.eye(4)
        t0, T0 = self._last
        dt = max(0.0, float(t) - t0)
        return T0 @ exp_se3(self._twist * dt)

    def update(self, t: float, T: np.ndarray, measured: bool = True) -> None:
        """Record the pose at time ``t``; the velocity is re-estimated only from measured poses."""
        if self._last is not None and measured:
            t0, T0 = self._last
            dt = float(t) - t0
            if dt > 1e-6:
                self._twist = log_se3(invert(T0) @ T) / dt
        self._missed = 0 if measured else self._missed + 1
        if self._missed > HOLD_AFTER:
            self._twist = 0.5 * self._twist
        self._last = (float(t), np.array(T, dtype=np.float64))
