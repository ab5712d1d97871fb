"""SE(3) exponential and logarithm on 4×4 matrices (twist ``ξ = [v, ω]``: translation part first, metres and
radians), used by the odometry's Gauss-Newton updates. Composition convention: ``exp(ξ) @ T`` is a left
(parent-frame) perturbation of ``T``."""

from __future__ import annotations

import numpy as np


def hat(w: np.ndarray) -> np.ndarray:
    """Skew-symmetric 3×3 matrix of ``w`` (``hat(w) @ p == cross(w, p)``)."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def exp_se3(xi: np.ndarray) -> np.ndarray:
    """4×4 rigid transform of the twist ``xi = [vx, vy, vz, wx, wy, wz]``."""
    xi = np.asarray(xi, dtype=np.float64)
    v, w = xi[:3], xi[3:]
    th = float(np.linalg.norm(w))
    W = hat(w)
    if th < 1e-9:
        R = np.eye(3) + W
        V = np.eye(3) + 0.5 * W
    else:
        a = np.sin(th) / th
        b = (1.0 - np.cos(th)) / th**2
        c = (th - np.sin(th)) / th**3
        R = np.eye(3) + a * W + b * (W @ W)
        V = np.eye(3) + b * W + c * (W @ W)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = V @ v
    return T


def log_se3(T: np.ndarray) -> np.ndarray:
    """Twist ``[v, ω]`` with ``exp_se3(log_se3(T)) == T`` (rotation angle below π)."""
    R, t = T[:3, :3], T[:3, 3]
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    th = float(np.arccos(cos))
    if th < 1e-9:
        w = 0.5 * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
        V_inv = np.eye(3) - 0.5 * hat(w)
    else:
        w = th / (2.0 * np.sin(th)) * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
        W = hat(w)
        V_inv = np.eye(3) - 0.5 * W + (1.0 / th**2) * (1.0 - (th * np.sin(th)) / (2.0 * (1.0 - np.cos(th)))) * (W @ W)
    return np.concatenate([V_inv @ t, w])


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of a 4×4 rigid transform."""
    out = np.eye(4)
    R = T[:3, :3]
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    return out


def motion_size(T: np.ndarray) -> tuple[float, float]:
    """``(translation in metres, rotation angle in radians)`` of a rigid transform."""
    cos = np.clip((np.trace(T[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.linalg.norm(T[:3, 3])), float(np.arccos(cos))
