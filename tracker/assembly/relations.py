"""Relative poses and pose-equality tests (spec sections 6–7, eqs 5.1–5.14, eq. 5.8 corrected).

All poses are camera-frame :class:`~tracker.geometry.pose.Pose` values (metres). The table frame follows the project
convention: y = the table's upward unit normal, x = the camera x axis projected onto the table plane,
z = x × y (pointing towards the user for a camera looking down at the table).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from tracker.geometry.pose import Pose, matrix_to_quat


def table_rotation(table_to_camera: Pose) -> np.ndarray:
    """``R_OT`` (3×3): maps camera-frame vectors to table-frame coordinates (eq. 5.8 corrected).

    Its rows are the table axes expressed in the camera frame, so ``(R_OT @ v)[1] = N_table · v``.
    """
    return table_to_camera.R.T


def table_rotation_from_normal(normal: np.ndarray) -> np.ndarray:
    """``R_OT`` built from the upward table normal (camera frame): rows x (camera x projected), N, x × N."""
    y = np.asarray(normal, float)
    y = y / np.linalg.norm(y)
    x = np.array([1.0, 0.0, 0.0]) - y[0] * y
    if np.linalg.norm(x) < 1e-6:  # camera x parallel to the normal: fall back to camera z
        x = np.array([0.0, 0.0, 1.0]) - y[2] * y
    x /= np.linalg.norm(x)
    return np.stack([x, y, cross3(x, y)])


def table_to_camera_from_plane(normal: np.ndarray, offset: float) -> Pose:
    """Table frame → camera frame for the plane ``normal·p + offset = 0`` (origin: optical axis ∩ plane)."""
    n = np.asarray(normal, float)
    scale = np.linalg.norm(n)
    n, offset = n / scale, offset / scale
    R_ot = table_rotation_from_normal(n)
    if abs(n[2]) < 1e-9:
        raise ValueError("the camera's optical axis is parallel to the table plane")
    origin = np.array([0.0, 0.0, -offset / n[2]])
    return Pose.from_rt(R_ot.T, origin)


def relative_position_table(p_a: np.ndarray, p_b: np.ndarray, R_ot: np.ndarray) -> np.ndarray:
    """Position of b relative to a in table-aligned coordinates: ``R_OT (p_b − p_a)`` (eq. 5.8 corrected)."""
    return R_ot @ (np.asarray(p_b, float) - np.asarray(p_a, float))


def cross3(u, v) -> np.ndarray:
    """``np.cross(u, v)`` of two 3-vectors, the same float64 bits, without np.cross's general-case overhead (about
    20 us a call; the connection checks make a dozen a frame); other shapes or dtypes go to ``np.cross``."""
    a, b = np.asarray(u), np.asarray(v)
    if a.shape != (3,) or b.shape != (3,) or np.result_type(a, b) != np.float64:
        return np.cross(a, b)
    a0, a1, a2 = a.tolist()
    b0, b1, b2 = b.tolist()
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def norm3(v) -> float:
    """``np.linalg.norm(v)`` of a float64 vector, the same bits (numpy's own steps: the vector flattened in memory
    order, its dot product with itself, the square root), without its general-case overhead (about 3 us a call; the
    connection checks make dozens a frame); other dtypes go to ``np.linalg.norm``."""
    x = np.asarray(v)
    if x.dtype != np.float64:
        return float(np.linalg.norm(x))
    x = x.ravel(order="K")
    return math.sqrt(x.dot(x))


def relative_pose(pose_a: Pose, pose_b: Pose) -> tuple[np.ndarray, np.ndarray]:
    """``(p_ab, R_ab)``: b's position and rotation in a's body frame (eqs 5.1–5.3)."""
    R_a = pose_a.R
    return R_a.T @ (pose_b.t - pose_a.t), R_a.T @ pose_b.R


@functools.lru_cache(maxsize=64)
def _scalar_margins(m_p: float) -> np.ndarray:
    """Read-only ``(m_p, m_p, m_p)`` (m), made once per value: the connection checks ask about 20 times a frame."""
    if m_p <= 0:
        raise ValueError(f"position margins must be positive, got {m_p}")
    m = np.full(3, float(m_p))
    m.setflags(write=False)
    return m


def margins(m_p: float | tuple[float, float, float]) -> np.ndarray:
    """Per-axis position margins ``(m_p,x, m_p,y, m_p,z)`` in metres (read-only for a single number)."""
    if isinstance(m_p, float | int) and not isinstance(m_p, bool):  # the usual case, without broadcasting
        return _scalar_margins(m_p)
    m = np.broadcast_to(np.asarray(m_p, float), (3,)).copy()
    if np.any(m <= 0):
        raise ValueError(f"position margins must be positive, got {m_p}")
    return m


def position_within(p_des: np.ndarray, p_real: np.ndarray, m_p) -> bool:
    """Per-axis position test (eq. 5.11)."""
    return bool(np.all(np.abs(np.asarray(p_des) - np.asarray(p_real)) < margins(m_p)))


def normalised_position_error(p_des: np.ndarray, p_real: np.ndarray, m_p) -> float:
    """``Σ ((p_des,i − p_real,i) / m_p,i)²`` (the bracket of eq. 5.16 without the −3)."""
    d = (np.asarray(p_des, float) - np.asarray(p_real, float)) / margins(m_p)
    return float(d @ d)


def m_q_from_angle(theta_max: float) -> float:
    """Rotation margin ``m_q = 1 − cos(θ_max / 2)`` for an angular tolerance θ_max in radians (section 7)."""
    return float(1.0 - np.cos(theta_max / 2.0))


def rotation_within(R_des: np.ndarray, R_real: np.ndarray, m_q: float) -> bool:
    """Rotation test ``|q_des · q_real| ≥ 1 − m_q`` (eq. 5.13)."""
    return bool(abs(float(matrix_to_quat(R_des) @ matrix_to_quat(R_real))) >= 1.0 - m_q)


def rotation_dot(R_des: np.ndarray, R_real: np.ndarray) -> float:
    """``|q_des · q_real|`` = cos(Δθ / 2)."""
    c = (np.trace(np.asarray(R_des).T @ np.asarray(R_real)) - 1.0) / 2.0
    return math.sqrt(min(max(float((1.0 + c) / 2.0), 0.0), 1.0))  # = np.sqrt(np.clip(...)), NaN too
