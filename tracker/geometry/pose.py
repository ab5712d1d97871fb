"""Rigid poses and Hamilton quaternions.

A :class:`Pose` maps points from a body frame into a parent frame (usually the camera frame):
``p_parent = R @ p_body + t``. Translations are in metres; quaternions are Hamilton ``[x, y, z, w]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation


def normalize_quat(q: np.ndarray) -> np.ndarray:
    """Unit quaternion(s) ``[..., 4]`` in ``[x, y, z, w]`` order with ``w >= 0``."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n < 1e-12):
        raise ValueError("zero-length quaternion")
    q = q / n
    return np.where(q[..., 3:4] < 0, -q, q)


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` of ``[x, y, z, w]`` quaternions (rotate by b first, then a)."""
    ax, ay, az, aw = np.moveaxis(np.asarray(a, dtype=np.float64), -1, 0)
    bx, by, bz, bw = np.moveaxis(np.asarray(b, dtype=np.float64), -1, 0)
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix/matrices ``[..., 3, 3]`` of Hamilton ``[x, y, z, w]`` quaternion(s)."""
    return Rotation.from_quat(np.asarray(q, dtype=np.float64)).as_matrix()


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Hamilton ``[x, y, z, w]`` quaternion(s) with ``w >= 0`` of rotation matrix/matrices."""
    return normalize_quat(Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_quat())


def rotation_angle(q_a: np.ndarray, q_b: np.ndarray) -> np.ndarray:
    """Angle in radians of the rotation between two orientations (``[..., 4]`` quaternions)."""
    d = np.abs(np.sum(normalize_quat(q_a) * normalize_quat(q_b), axis=-1))
    return 2.0 * np.arccos(np.clip(d, 0.0, 1.0))


@dataclass(frozen=True)
class Pose:
    """Rigid transform body → parent: translation ``t`` (metres) and Hamilton quaternion ``q`` [x,y,z,w]."""

    t: np.ndarray = field(default_factory=lambda: np.zeros(3))
    q: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 0.0, 1.0]))

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=np.float64).reshape(3)
        q = normalize_quat(np.asarray(self.q, dtype=np.float64).reshape(4))
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q))):
            raise ValueError("pose has non-finite values")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "q", q)

    @staticmethod
    def identity() -> Pose:
        return Pose()

    @staticmethod
    def from_matrix(T: np.ndarray) -> Pose:
        """Pose from a 4×4 homogeneous matrix (rotation part is re-orthonormalised)."""
        T = np.asarray(T, dtype=np.float64)
        if T.shape != (4, 4):
            raise ValueError(f"expected a 4x4 matrix, got shape {T.shape}")
        return Pose(T[:3, 3], matrix_to_quat(T[:3, :3]))

    @staticmethod
    def from_rt(R: np.ndarray, t: np.ndarray) -> Pose:
        return Pose(np.asarray(t), matrix_to_quat(R))

    @staticmethod
    def from_rotvec(rotvec: np.ndarray, t: np.ndarray) -> Pose:
        return Pose(np.asarray(t), Rotation.from_rotvec(np.asarray(rotvec, dtype=np.float64)).as_quat())

    @property
    def R(self) -> np.ndarray:
        """3×3 rotation matrix."""
        return quat_to_matrix(self.q)

    def as_matrix(self) -> np.ndarray:
        """4×4 homogeneous matrix."""
        T = np.eye(4)
        T[:3, :3] = self.R
        T[:3, 3] = self.t
        return T

    def inverse(self) -> Pose:
        R = self.R
        return Pose.from_rt(R.T, -R.T @ self.t)

    def __matmul__(self, other: Pose) -> Pose:
        """Composition: ``(self @ other)`` maps other's body frame through other, then self."""
        return Pose(self.R @ other.t + self.t, quat_multiply(self.q, other.q))

    def transform_points(self, pts: np.ndarray) -> np.ndarray:
        """Map body-frame points ``[N, 3]`` into the parent frame."""
        return np.asarray(pts, dtype=np.float64) @ self.R.T + self.t

    def to_dict(self) -> dict[str, list[float]]:
        """JSON form ``{"t": [x, y, z], "q": [x, y, z, w]}`` as used by recordings."""
        return {"t": [float(v) for v in self.t], "q": [float(v) for v in self.q]}

    @staticmethod
    def from_dict(d: dict) -> Pose:
        try:
            return Pose(np.asarray(d["t"], dtype=np.float64), np.asarray(d["q"], dtype=np.float64))
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"invalid pose {d!r}: {exc}") from exc

    def translation_error(self, other: Pose) -> float:
        """Euclidean distance between translations, metres."""
        return float(np.linalg.norm(self.t - other.t))

    def rotation_error(self, other: Pose) -> float:
        """Angle between orientations, radians (no symmetry; see tracker.geometry.symmetry for parts)."""
        return float(rotation_angle(self.q, other.q))
