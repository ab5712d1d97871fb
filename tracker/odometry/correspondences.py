"""Numba kernels of the dense alignment: per-point correspondences, residuals and Jacobian rows of the photometric
and point-to-plane terms for one Gauss-Newton iteration (see :mod:`.dense_alignment` for the formulation).

Frames: keyframe points in the keyframe camera frame; ``T_ck`` maps them into the current camera frame
(4×4, metres). Pixels: column u, row v, pixel centres at integers.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def photometric_terms(points, values, jac, T_ck, gray, mask, fx, fy, cx, cy, ref_out, cur_out, jac_out):
    """For every keyframe point seen in the current image on an unmasked pixel: its keyframe grey value
    (``ref_out``), the current image's bilinear grey value where it projects (``cur_out``) and its Jacobian row
    (``jac_out``). Returns how many were written."""
    h, w = gray.shape
    n = 0
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        xc = T_ck[0, 0] * x + T_ck[0, 1] * y + T_ck[0, 2] * z + T_ck[0, 3]
        yc = T_ck[1, 0] * x + T_ck[1, 1] * y + T_ck[1, 2] * z + T_ck[1, 3]
        zc = T_ck[2, 0] * x + T_ck[2, 1] * y + T_ck[2, 2] * z + T_ck[2, 3]
        if zc <= 0.05:
            continue
        u = fx * xc / zc + cx
        v = fy * yc / zc + cy
        if u < 0.0 or v < 0.0 or u > w - 1.001 or v > h - 1.001:
            continue
        if mask[int(v + 0.5), int(u + 0.5)]:
            continue
        u0, v0 = int(u), int(v)
        a, b = u - u0, v - v0
        val = ((1 - a) * (1 - b) * gray[v0, u0] + a * (1 - b) * gray[v0, u0 + 1]
               + (1 - a) * b * gray[v0 + 1, u0] + a * b * gray[v0 + 1, u0 + 1])
        ref_out[n] = values[i]
        cur_out[n] = val
        for k in range(6):
            jac_out[n, k] = jac[i, k]
        n += 1
    return n


@nb.njit(cache=True)
def geometric_terms(points, normals, T_ck, T_kc, depth, mask, fx, fy, cx, cy, max_dist, r_out, jac_out):
    """Point-to-plane residuals ``n·(T_kc q − p)`` with projective association and their Jacobian rows
    ``[n, q × n]``. Returns ``(written, seen)``: correspondences kept (closer than ``max_dist``) and keyframe
    points that landed on a valid, unmasked depth pixel."""
    h, w = depth.shape
    n = 0
    seen = 0
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        xc = T_ck[0, 0] * x + T_ck[0, 1] * y + T_ck[0, 2] * z + T_ck[0, 3]
        yc = T_ck[1, 0] * x + T_ck[1, 1] * y + T_ck[1, 2] * z + T_ck[1, 3]
        zc = T_ck[2, 0] * x + T_ck[2, 1] * y + T_ck[2, 2] * z + T_ck[2, 3]
        if zc <= 0.05:
            continue
        ui = int(fx * xc / zc + cx + 0.5)
        vi = int(fy * yc / zc + cy + 0.5)
        if ui < 0 or vi < 0 or ui >= w or vi >= h:
            continue
        d = depth[vi, ui]
        if not (d > 0.0) or mask[vi, ui]:
            continue
        seen += 1
        qx = (ui - cx) * d / fx
        qy = (vi - cy) * d / fy
        qz = d
        kx = T_kc[0, 0] * qx + T_kc[0, 1] * qy + T_kc[0, 2] * qz + T_kc[0, 3]
        ky = T_kc[1, 0] * qx + T_kc[1, 1] * qy + T_kc[1, 2] * qz + T_kc[1, 3]
        kz = T_kc[2, 0] * qx + T_kc[2, 1] * qy + T_kc[2, 2] * qz + T_kc[2, 3]
        dx, dy, dz = kx - x, ky - y, kz - z
        if dx * dx + dy * dy + dz * dz > max_dist * max_dist:
            continue
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        r_out[n] = nx * dx + ny * dy + nz * dz
        jac_out[n, 0] = nx
        jac_out[n, 1] = ny
        jac_out[n, 2] = nz
        jac_out[n, 3] = ky * nz - kz * ny
        jac_out[n, 4] = kz * nx - kx * nz
        jac_out[n, 5] = kx * ny - ky * nx
        n += 1
    return n, seen


def empty_buffers(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scratch arrays for ``n`` points: two value vectors and a Jacobian block."""
    return np.empty(n), np.empty(n), np.empty((n, 6))
