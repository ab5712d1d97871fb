"""Rigid poses and Hamilton quaternions.

A :class:`Pose` maps points from a body frame into a parent frame (usually the camera frame):
``p_parent = R @ p_body + t``. Translations are in metres; quaternions are Hamilton ``[x, y, z, w]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba as nb
import numpy as np
from scipy.spatial.transform import Rotation


def normalize_quat(q: np.ndarray) -> np.ndarray:
    """Unit quaternion(s) ``[..., 4]`` in ``[x, y, z, w]`` order with ``w >= 0``."""
    q = np.asarray(q, dtype=np.float64)
    if q.shape == (4,):
        return _normalize_quat_one(*q.tolist())
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(n < 1e-12):
        raise ValueError("zero-length quaternion")
    q = q / n
    return np.where(q[..., 3:4] < 0, -q, q)


def _normalize_quat_one(x: float, y: float, z: float, w: float) -> np.ndarray:
    """:func:`normalize_quat` of one quaternion in plain floats (the same operations, bit-identical)."""
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if n < 1e-12:
        raise ValueError("zero-length quaternion")
    if w / n < 0:
        return np.array([-x / n, -y / n, -z / n, -w / n])
    return np.array([x / n, y / n, z / n, w / n])


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` of ``[x, y, z, w]`` quaternions (rotate by b first, then a)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape == (4,) and b.shape == (4,):  # one pair (a pose composition): the same products in plain floats
        return _quat_multiply_one(*a.tolist(), *b.tolist())
    ax, ay, az, aw = np.moveaxis(a, -1, 0)
    bx, by, bz, bw = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


def _quat_multiply_one(ax: float, ay: float, az: float, aw: float, bx: float, by: float, bz: float,
                       bw: float) -> np.ndarray:
    """:func:`quat_multiply` of one pair of quaternions in plain floats (the same operations in the same order,
    bit-identical, at a twentieth of the array form's time)."""
    return np.array([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz])


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix/matrices ``[..., 3, 3]`` of Hamilton ``[x, y, z, w]`` quaternion(s) (normalised first).

    Closed form, the same floating-point operations in the same order as scipy's ``Rotation.from_quat(q)
    .as_matrix()`` (bit-identical results, without its per-call overhead of a few hundred microseconds)."""
    q = np.asarray(q, dtype=np.float64)
    if q.shape == (4,):
        return _quat_to_matrix_one(float(q[0]), float(q[1]), float(q[2]), float(q[3]))
    if q.shape[-1:] != (4,):
        raise ValueError(f"expected quaternions of shape (..., 4), got {q.shape}")
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    n = np.sqrt(x * x + y * y + z * z + w * w)
    if np.any(n == 0.0):
        raise ValueError("zero-length quaternion")
    x, y, z, w = x / n, y / n, z / n, w / n
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    m = np.stack(
        [x2 - y2 - z2 + w2, 2 * (xy - zw), 2 * (xz + yw),
         2 * (xy + zw), -x2 + y2 - z2 + w2, 2 * (yz - xw),
         2 * (xz - yw), 2 * (yz + xw), -x2 - y2 + z2 + w2],
        axis=-1,
    )  # fmt: skip
    return m.reshape(*q.shape[:-1], 3, 3)


def _quat_to_matrix_one(x: float, y: float, z: float, w: float) -> np.ndarray:
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if n == 0.0:
        raise ValueError("zero-length quaternion")
    x, y, z, w = x / n, y / n, z / n, w / n
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    return np.array(
        [[x2 - y2 - z2 + w2, 2 * (xy - zw), 2 * (xz + yw)],
         [2 * (xy + zw), -x2 + y2 - z2 + w2, 2 * (yz - xw)],
         [2 * (xz - yw), 2 * (yz + xw), -x2 - y2 + z2 + w2]]
    )  # fmt: skip


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Hamilton ``[x, y, z, w]`` quaternion(s) with ``w >= 0`` of rotation matrix/matrices ``[..., 3, 3]``.

    A matrix that is not orthonormal (its Gram matrix not within ``isclose(·, I, atol=1e-12)``) is replaced by
    the nearest rotation (SVD) first; a non-positive determinant is a ValueError. Shepperd's method with the same
    floating-point operations as scipy's ``Rotation.from_matrix(R).as_quat()`` (bit-identical results, without
    its per-call overhead)."""
    R = np.asarray(R, dtype=np.float64)
    if R.shape == (3, 3):
        # the compiled kernel (same operations) for an orthonormal matrix; the Python form projects any other one
        # and raises for a non-positive determinant
        q, status = _matrices_to_quats(np.ascontiguousarray(R).reshape(1, 3, 3), True)
        if status[0] == 0:
            return q[0]
        return normalize_quat(_matrix_to_quat_one(R))
    if R.shape[-2:] != (3, 3):
        raise ValueError(f"expected rotation matrices of shape (..., 3, 3), got {R.shape}")
    flat = np.ascontiguousarray(R.reshape(-1, 3, 3))
    q, status = _matrices_to_quats(flat, True)
    if np.any(status == 2):
        raise ValueError(f"non-positive determinant (left-handed or null coordinate frame) in rotation matrix {R}")
    redo = status == 1
    if np.any(redo):  # not orthonormal: the nearest rotation first
        U, _, Vt = np.linalg.svd(flat[redo], full_matrices=False)
        q[redo] = _matrices_to_quats(np.ascontiguousarray(U @ Vt), False)[0]
    return q.reshape(*R.shape[:-2], 4)


@nb.njit(cache=True)
def _matrices_to_quats(R, check):
    """Kernel of :func:`matrix_to_quat` for (M, 3, 3) matrices: quaternions (M, 4) and a status per matrix (0 done,
    1 not orthonormal: project it first, 2 non-positive determinant); ``check`` False skips both tests."""
    m = R.shape[0]
    out = np.zeros((m, 4))
    status = np.zeros(m, np.int64)
    for j in range(m):
        a, b, c = R[j, 0, 0], R[j, 0, 1], R[j, 0, 2]
        d, e, f = R[j, 1, 0], R[j, 1, 1], R[j, 1, 2]
        g, h, i = R[j, 2, 0], R[j, 2, 1], R[j, 2, 2]
        if check:
            if not a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) > 0:
                status[j] = 2
                continue
            orthonormal = True
            for r in range(3):
                for k in range(r, 3):
                    gram = R[j, r, 0] * R[j, k, 0] + R[j, r, 1] * R[j, k, 1] + R[j, r, 2] * R[j, k, 2]
                    eye = 1.0 if r == k else 0.0
                    if not abs(gram - eye) <= 1e-12 + 1e-5 * eye:
                        orthonormal = False
            if not orthonormal:
                status[j] = 1
                continue
        tr = a + e + i
        best = a
        choice = 0
        if e > best:
            best, choice = e, 1
        if i > best:
            best, choice = i, 2
        if tr > best:
            choice = 3
        if choice == 0:
            x, y, z, w = 1 - tr + 2 * a, d + b, g + c, h - f
        elif choice == 1:
            x, y, z, w = d + b, 1 - tr + 2 * e, h + f, c - g
        elif choice == 2:
            x, y, z, w = g + c, h + f, 1 - tr + 2 * i, d - b
        else:
            x, y, z, w = h - f, c - g, d - b, 1 + tr
        n = np.sqrt(x * x + y * y + z * z + w * w)
        x, y, z, w = x / n, y / n, z / n, w / n
        n = np.sqrt(x * x + y * y + z * z + w * w)  # normalize_quat's second pass, as on scipy's result
        x, y, z, w = x / n, y / n, z / n, w / n
        if w < 0:
            x, y, z, w = -x, -y, -z, -w
        out[j, 0], out[j, 1], out[j, 2], out[j, 3] = x, y, z, w
    return out, status


def _matrix_to_quat_one(m: np.ndarray) -> np.ndarray:
    """:func:`matrix_to_quat` of one 3×3 matrix in plain floats (the checks of the batch path, elementwise)."""
    rows = m.tolist()
    (a, b, c), (d, e, f), (g, h, i) = rows
    if not a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) > 0:
        raise ValueError(f"non-positive determinant (left-handed or null coordinate frame) in rotation matrix {m}")
    for r in range(3):
        for k in range(r, 3):
            gram = rows[r][0] * rows[k][0] + rows[r][1] * rows[k][1] + rows[r][2] * rows[k][2]
            if not abs(gram - (r == k)) <= 1e-12 + 1e-5 * (r == k):  # np.isclose(gram, I, atol=1e-12)
                U, _, Vt = np.linalg.svd(m[None], full_matrices=False)
                return _orthonormal_matrix_to_quat_one((U @ Vt)[0].tolist())
    return _orthonormal_matrix_to_quat_one(rows)


def _orthonormal_matrix_to_quat_one(rows: list[list[float]]) -> np.ndarray:
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = rows
    tr = m00 + m11 + m22
    decision = (m00, m11, m22, tr)
    c = decision.index(max(decision))  # the first of equal largest, as numpy's argmax
    if c == 0:
        q = (1 - tr + 2 * m00, m10 + m01, m20 + m02, m21 - m12)
    elif c == 1:
        q = (m10 + m01, 1 - tr + 2 * m11, m21 + m12, m02 - m20)
    elif c == 2:
        q = (m20 + m02, m21 + m12, 1 - tr + 2 * m22, m10 - m01)
    else:
        q = (m21 - m12, m02 - m20, m10 - m01, 1 + tr)
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return np.array([q[0] / n, q[1] / n, q[2] / n, q[3] / n])


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
        if not all(map(math.isfinite, t.tolist() + q.tolist())):
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
        """3×3 rotation matrix (a fresh array each time; computed once per pose, the pose being immutable)."""
        cached = self.__dict__.get("_R")
        if cached is None:
            cached = quat_to_matrix(self.q)
            object.__setattr__(self, "_R", cached)
        return cached.copy()

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
