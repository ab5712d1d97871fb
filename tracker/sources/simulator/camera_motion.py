"""Moving-camera models of the simulated table (``SimOptions.camera_motion``).

The camera moves around its nominal placement (:class:`~tracker.sources.simulator.scene.CameraPlacement`):
its pose in the table frame at time ``t`` is ``camera_to_table_nominal @ offset(t)``, where ``offset(t)`` is a
small rigid motion expressed in the nominal camera frame (x right, y down, z forward; metres, radians) — a
translation of the camera centre and a rotation about it.

Motions (every one a sum of seeded sinusoids, so any frame is computed directly from its time, in any order):

* ``"none"``: the fixed camera (offset = identity).
* ``"sway"``: slow smooth motion as of a camera on a flexible arm or held steadily by a person: per axis two
  sinusoids with periods of 4–14 s; translation amplitudes up to about 2 / 1.5 / 2 cm (x / y / z), rotation up
  to about 1.5° / 2° / 1° (pitch about x / yaw about y / roll about z).
* ``"handheld"``: the sway plus a faster small jitter: per axis three sinusoids with periods of 0.3–1.5 s,
  about 2 mm and 0.25° each.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tracker.geometry.pose import Pose

CAMERA_MOTIONS = ("none", "sway", "handheld")
"""Valid values of ``SimOptions.camera_motion``."""

SWAY_TRANSLATION = (0.02, 0.015, 0.02)
"""Per-axis translation amplitude bound of the sway, metres (camera x, y, z)."""
SWAY_ROTATION_DEG = (1.5, 2.0, 1.0)
"""Per-axis rotation amplitude bound of the sway, degrees (about camera x, y, z)."""
SWAY_PERIODS = (4.0, 14.0)
"""Range of the sway's sinusoid periods, seconds."""
JITTER_TRANSLATION = 0.002
"""Per-axis translation amplitude bound of the handheld jitter, metres."""
JITTER_ROTATION_DEG = 0.25
"""Per-axis rotation amplitude bound of the handheld jitter, degrees."""
JITTER_PERIODS = (0.3, 1.5)
"""Range of the jitter's sinusoid periods, seconds."""


@dataclass(frozen=True)
class _Sines:
    """Sum of sinusoids per degree of freedom: ``Σ_k amp[k, j] · sin(2π t / period[k, j] + phase[k, j])``."""

    amp: np.ndarray  # (K, 6)
    period: np.ndarray  # (K, 6)
    phase: np.ndarray  # (K, 6)

    def __call__(self, t: float) -> np.ndarray:
        return (self.amp * np.sin(2.0 * np.pi * t / self.period + self.phase)).sum(axis=0)


def _sines(rng: np.random.Generator, n: int, amp6: np.ndarray, periods: tuple[float, float]) -> _Sines:
    """``n`` sinusoids per dof whose amplitudes sum to at most ``amp6`` (weights drawn and normalised)."""
    w = rng.uniform(0.5, 1.0, size=(n, 6))
    w /= w.sum(axis=0, keepdims=True)
    period = rng.uniform(periods[0], periods[1], size=(n, 6))
    phase = rng.uniform(0.0, 2.0 * np.pi, size=(n, 6))
    return _Sines(w * amp6[None, :], period, phase)


class CameraMotion:
    """Seeded camera motion of kind ``kind`` (one of :data:`CAMERA_MOTIONS`); ``offset(t)`` is the camera's
    pose at time ``t`` (seconds) in the nominal camera frame."""

    def __init__(self, kind: str, rng: np.random.Generator) -> None:
        if kind not in CAMERA_MOTIONS:
            raise ValueError(f"camera motion must be one of {', '.join(CAMERA_MOTIONS)}, got {kind!r}")
        self.kind = kind
        self._terms: list[_Sines] = []
        if kind in ("sway", "handheld"):
            amp = np.concatenate([SWAY_TRANSLATION, np.radians(SWAY_ROTATION_DEG)])
            self._terms.append(_sines(rng, 2, amp, SWAY_PERIODS))
        if kind == "handheld":
            amp = np.array([JITTER_TRANSLATION] * 3 + [np.radians(JITTER_ROTATION_DEG)] * 3)
            self._terms.append(_sines(rng, 3, amp, JITTER_PERIODS))

    @property
    def moving(self) -> bool:
        return bool(self._terms)

    def offset_vector(self, t: float) -> np.ndarray:
        """``[tx, ty, tz, rx, ry, rz]``: translation (metres) and rotation vector (radians) at ``t`` seconds."""
        out = np.zeros(6)
        for term in self._terms:
            out += term(t)
        return out

    def offset(self, t: float) -> Pose:
        """The camera's pose at ``t`` seconds in the nominal camera frame (identity for ``"none"``)."""
        v = self.offset_vector(t)
        return Pose.from_rotvec(v[3:], v[:3])
