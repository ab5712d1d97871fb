"""Register a depth image to the colour camera (same pixel grid and intrinsics as the colour image).

A depth camera and a colour camera sit a few centimetres apart with different intrinsics. Each valid depth
pixel ``(u, v)`` with depth ``z`` (metres, depth-camera frame, x right, y down, z forward) is back-projected,
moved into the colour camera frame by ``depth_to_color`` (4×4, maps depth-frame points to colour-frame
points) and projected into the colour image. The pixel's footprint (its four corners at depth ``z``) is
splatted onto the colour pixels whose centres it covers, keeping the nearest depth per colour pixel
(z-buffer), so foreground surfaces correctly hide the background seen from the other viewpoint and a
lower-resolution depth image leaves no holes. Colour pixels that no depth pixel covers are NaN.
"""

from __future__ import annotations

import numba
import numpy as np

from tracker.geometry.camera import Intrinsics

MAX_SPLAT_PX = 8
"""Largest footprint (pixels per side) a single depth pixel may cover in the colour image."""


@numba.njit(cache=True)
def _splat(depth, dint, R, t, cint, out):  # pragma: no cover - compiled
    fx_d, fy_d, cx_d, cy_d = dint[0], dint[1], dint[2], dint[3]
    fx_c, fy_c, cx_c, cy_c = cint[0], cint[1], cint[2], cint[3]
    h, w = depth.shape
    hc, wc = out.shape
    for v in range(h):
        for u in range(w):
            z = depth[v, u]
            if not (z > 0.0):  # also skips NaN
                continue
            # centre of the pixel in the colour frame
            x = (u - cx_d) / fx_d * z
            y = (v - cy_d) / fy_d * z
            zc = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z + t[2]
            if zc <= 1e-6:
                continue
            xc = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z + t[0]
            yc = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z + t[1]
            pu = fx_c * xc / zc + cx_c
            pv = fy_c * yc / zc + cy_c
            # footprint: the four pixel corners at the same depth
            umin = 1e30
            umax = -1e30
            vmin = 1e30
            vmax = -1e30
            ok = True
            for k in range(4):
                du = -0.5 if k < 2 else 0.5
                dv = -0.5 if (k % 2) == 0 else 0.5
                x1 = (u + du - cx_d) / fx_d * z
                y1 = (v + dv - cy_d) / fy_d * z
                Z = R[2, 0] * x1 + R[2, 1] * y1 + R[2, 2] * z + t[2]
                if Z <= 1e-6:
                    ok = False
                    break
                X = R[0, 0] * x1 + R[0, 1] * y1 + R[0, 2] * z + t[0]
                Y = R[1, 0] * x1 + R[1, 1] * y1 + R[1, 2] * z + t[1]
                cu = fx_c * X / Z + cx_c
                cv = fy_c * Y / Z + cy_c
                umin = min(umin, cu)
                umax = max(umax, cu)
                vmin = min(vmin, cv)
                vmax = max(vmax, cv)
            if not ok:
                continue
            # colour pixel centres c with umin <= c < umax; at least the pixel nearest the centre
            x0 = int(np.ceil(umin))
            x1i = int(np.ceil(umax)) - 1
            if x0 > x1i or x1i - x0 >= 8:
                x0 = int(np.floor(pu + 0.5))
                x1i = x0
            y0 = int(np.ceil(vmin))
            y1i = int(np.ceil(vmax)) - 1
            if y0 > y1i or y1i - y0 >= 8:
                y0 = int(np.floor(pv + 0.5))
                y1i = y0
            if x1i < 0 or y1i < 0 or x0 >= wc or y0 >= hc:
                continue
            x0 = max(x0, 0)
            y0 = max(y0, 0)
            x1i = min(x1i, wc - 1)
            y1i = min(y1i, hc - 1)
            for yy in range(y0, y1i + 1):
                for xx in range(x0, x1i + 1):
                    if zc < out[yy, xx]:
                        out[yy, xx] = zc


def register_depth(
    depth: np.ndarray, depth_intrinsics: Intrinsics, color_intrinsics: Intrinsics, depth_to_color: np.ndarray
) -> np.ndarray:
    """Depth (metres, ``float32``, NaN missing) on the colour camera's pixel grid.

    * ``depth``: H_d×W_d metres in the depth camera, NaN or ≤ 0 where missing.
    * ``depth_intrinsics`` / ``color_intrinsics``: pinhole intrinsics of the two images (no distortion).
    * ``depth_to_color``: 4×4 rigid transform mapping depth-camera-frame points to the colour camera frame.

    Returns an H_c×W_c ``float32`` image of z in the colour camera frame.
    """
    depth = np.asarray(depth, dtype=np.float32)
    if depth.shape != (depth_intrinsics.height, depth_intrinsics.width):
        raise ValueError(
            f"depth image is {depth.shape[1]}x{depth.shape[0]} but the depth intrinsics say "
            f"{depth_intrinsics.width}x{depth_intrinsics.height}"
        )
    T = np.asarray(depth_to_color, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"depth_to_color must be a 4x4 matrix, got shape {T.shape}")
    out = np.full((color_intrinsics.height, color_intrinsics.width), np.inf, dtype=np.float32)
    dint = np.array([depth_intrinsics.fx, depth_intrinsics.fy, depth_intrinsics.cx, depth_intrinsics.cy])
    cint = np.array([color_intrinsics.fx, color_intrinsics.fy, color_intrinsics.cx, color_intrinsics.cy])
    _splat(np.ascontiguousarray(depth), dint, np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]),
           cint, out)
    out[np.isinf(out)] = np.nan
    return out
