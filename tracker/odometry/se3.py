"""SE(3) exponential and logarithm on 4×4 matrices (twist ``ξ = [v, ω]``: translation part first, metres and
radians), used by the odometry's Gauss-Newton updates. Composition convention: ``exp(ξ) @ T`` is a left
(parent-frame) perturbation of ``T``."""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)
def hat(w):
    """Skew-symmetric 3×3 matrix of ``w`` (``hat(w) @ p == cross(w, p)``)."""
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


@nb.njit(cache=True, nogil=True)
def exp_twist(xi):
    """4×4 rigid transform of the twist ``xi = [vx, vy, vz, wx, wy, wz]`` (float64 array; compiled, also called
    from the compiled Gauss-Newton loop of :mod:`.gauss_newton`)."""
    v, w = xi[:3].copy(), xi[3:].copy()
    th = np.sqrt(w[0] ** 2 + w[1] ** 2 + w[2] ** 2)
    W = hat(w)
    W2 = W @ W
    if th < 1e-9:
        R = np.eye(3) + W
        V = np.eye(3) + 0.5 * W
    else:
        a = np.sin(th) / th
        b = (1.0 - np.cos(th)) / th**2
        c = (th - np.sin(th)) / th**3
        R = np.eye(3) + a * W + b * W2
        V = np.eye(3) + b * W + c * W2
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = V @ v
    return T


@nb.njit(cache=True, nogil=True)
def log_twist(T):
    """Twist ``[v, ω]`` of a 4×4 rigid transform with ``exp_twist(log_twist(T)) == T`` (rotation angle below π;
    compiled)."""
    R = T[:3, :3]
    t = T[:3, 3].copy()
    cos = min(max((R[0, 0] + R[1, 1] + R[2, 2] - 1.0) / 2.0, -1.0), 1.0)
    th = np.arccos(cos)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if th < 1e-9:
        w = 0.5 * w
        V_inv = np.eye(3) - 0.5 * hat(w)
    else:
        w = th / (2.0 * np.sin(th)) * w
        W = hat(w)
        V_inv = np.eye(3) - 0.5 * W + (1.0 / th**2) * (1.0 - (th * np.sin(th)) / (2.0 * (1.0 - np.cos(th)))) * (W @ W)
    out = np.empty(6)
    out[:3] = V_inv @ t
    out[3:] = w
    return out


@nb.njit(cache=True, nogil=True)
def invert_rigid(T):
    """Inverse of a 4×4 rigid transform (compiled)."""
    out = np.eye(4)
    for i in range(3):
        for j in range(3):
            out[i, j] = T[j, i]
    for i in range(3):
        out[i, 3] = -(T[0, i] * T[0, 3] + T[1, i] * T[1, 3] + T[2, i] * T[2, 3])
    return out


def exp_se3(xi) -> np.ndarray:
    """4×4 rigid transform of the twist ``xi = [vx, vy, vz, wx, wy, wz]`` (any sequence of six numbers)."""
    return exp_twist(np.asarray(xi, dtype=np.float64).reshape(6))


def log_se3(T) -> np.ndarray:
    """Twist ``[v, ω]`` with ``exp_se3(log_se3(T)) == T`` (rotation angle below π)."""
    return log_twist(np.ascontiguousarray(T, dtype=np.float64))


def invert(T) -> np.ndarray:
    """Inverse of a 4×4 rigid transform."""
    return invert_rigid(np.ascontiguousarray(T, dtype=np.float64))


def motion_size(T: np.ndarray) -> tuple[float, float]:
    """``(translation in metres, rotation angle in radians)`` of a rigid transform. The trace is summed and clipped on
    Python floats as ``np.trace`` and ``np.clip`` form them (the same values, without their per-call overhead)."""
    T = np.asarray(T)
    cos = ((float(T[0, 0]) + float(T[1, 1]) + float(T[2, 2])) - 1.0) / 2.0
    return float(np.linalg.norm(T[:3, 3])), float(np.arccos(min(max(cos, -1.0), 1.0)))
