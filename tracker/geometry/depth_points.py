"""Camera-frame points of a depth-image window, filtered in one compiled pass (numba).

The hand carry (:mod:`tracker.filter.hand_carry`) takes the hand's points around a part several times a frame from
windows of up to ~300 × 300 pixels; done with numpy this builds half a dozen full-window temporaries per call. This
kernel visits the window once and writes only the points kept. The point of pixel (u, v) with depth d (m) is
((u − cx) / fx · d, (v − cy) / fy · d, d), computed with the same operations in the same order as the numpy version,
so the points are the same to the bit.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def window_points(depth: np.ndarray, u0: int, u1: int, v0: int, v1: int, stride: int, fx: float, fy: float,
                  cx: float, cy: float, center: np.ndarray, radius2: float, normal: np.ndarray, offset: float,
                  min_height: float, use_plane: bool, ex_centers: np.ndarray, ex_radii2: np.ndarray) -> np.ndarray:
    """Points (M, 3) (camera frame, m) of the pixels ``depth[v0:v1:stride, u0:u1:stride]`` (row by row) with a
    finite positive depth (m), within squared distance ``radius2`` (m²) of ``center``, higher than ``min_height``
    above the plane n·x + ``offset`` (only with ``use_plane``) and farther than squared distance ``ex_radii2[e]``
    from every ``ex_centers[e]`` (E, 3)."""
    nv = (v1 - v0 + stride - 1) // stride
    nu = (u1 - u0 + stride - 1) // stride
    out = np.empty((max(nv * nu, 0), 3))
    m = 0
    c0, c1, c2 = center[0], center[1], center[2]
    n0, n1, n2 = normal[0], normal[1], normal[2]
    for v in range(v0, v1, stride):
        for u in range(u0, u1, stride):
            d = np.float64(depth[v, u])
            if not (np.isfinite(d) and d > 0):
                continue
            x = (u - cx) / fx * d
            y = (v - cy) / fy * d
            dx, dy, dz = x - c0, y - c1, d - c2
            if dx * dx + dy * dy + dz * dz > radius2:
                continue
            if use_plane and not (x * n0 + y * n1 + d * n2 + offset > min_height):
                continue
            kept = True
            for e in range(ex_centers.shape[0]):
                ex, ey, ez = x - ex_centers[e, 0], y - ex_centers[e, 1], d - ex_centers[e, 2]
                if ex * ex + ey * ey + ez * ez <= ex_radii2[e]:
                    kept = False
                    break
            if kept:
                out[m, 0], out[m, 1], out[m, 2] = x, y, d
                m += 1
    return out[:m].copy()
