"""The table as a constraint on the camera's pose (issue 15; not in the seed).

The table is a large static plane: seen in a frame, its normal and offset fix three of the camera's six degrees of
freedom (the two tilts and the height above it) to a fraction of a millimetre, from thousands of depth pixels. The
plane is known in the world frame (``n_w · x + d_w = 0``, ``n_w`` the upward unit normal, metres); a camera pose
``T`` (camera → world) predicts it in the camera frame as ``n_c = Rᵀ n_w``, ``d_c = d_w + n_w · t``.

:func:`refit_plane` measures the plane in a depth image near where a pose predicts it (a thin band keeps hands,
arms and parts, which stand out of the plane, away), and :func:`apply_plane` turns the camera about its centre and
shifts it along the normal so that its prediction matches the measured plane, leaving the other three degrees of
freedom (yaw about the normal, sliding along the table) as they were.
"""

from __future__ import annotations

import numpy as np

from tracker.geometry.camera import Intrinsics
from tracker.perception.table_plane import fit_plane_svd

BAND_M = 0.005
"""Depth pixels within this distance (metres) of the predicted plane are table pixels for :func:`refit_plane`."""
STEP_PX = 6
"""Pixel grid step of the samples :func:`refit_plane` takes (every 6th row and column: ~8500 samples at 640×480)."""
MIN_POINTS = 2000
"""Fewest table samples for a measured plane (fewer: the table is mostly hidden; no measurement)."""


def plane_in_camera(T: np.ndarray, n_w: np.ndarray, d_w: float) -> tuple[np.ndarray, float]:
    """The world plane ``(n_w, d_w)`` in the camera frame of the camera pose ``T`` (4×4 camera → world)."""
    R, t = T[:3, :3], T[:3, 3]
    return R.T @ n_w, float(d_w + n_w @ t)


def refit_plane(depth: np.ndarray, intrinsics: Intrinsics, n_c: np.ndarray, d_c: float,
                mask: np.ndarray | None = None, band: float = BAND_M,
                step: int = STEP_PX) -> tuple[np.ndarray, float] | None:
    """The table plane ``(n, d)`` (camera frame, ``n`` oriented like ``n_c``) fitted to the depth pixels within
    ``band`` of the predicted plane ``(n_c, d_c)``, outside ``mask`` (True = exclude); None with too few of them."""
    d = depth[::step, ::step]
    h, w = d.shape
    u = (np.arange(w, dtype=np.float64) * step - intrinsics.cx) / intrinsics.fx
    v = (np.arange(h, dtype=np.float64) * step - intrinsics.cy) / intrinsics.fy
    z = d.astype(np.float64)
    pts = np.stack([u[None, :] * z, v[:, None] * z, z], axis=-1)
    with np.errstate(invalid="ignore"):
        keep = np.isfinite(z) & (z > 0) & (np.abs(pts @ n_c + d_c) < band)
    if mask is not None:
        keep &= ~mask[::step, ::step]
    if int(keep.sum()) < MIN_POINTS:
        return None
    # (np.take of the flat indices: the rows of pts[keep], at a seventh of a boolean index's time)
    n, off = fit_plane_svd(np.take(pts.reshape(-1, 3), np.flatnonzero(keep), axis=0))
    if n @ n_c < 0:
        n, off = -n, -off
    return n, float(off)


def apply_plane(T: np.ndarray, n_w: np.ndarray, d_w: float, n_obs: np.ndarray, d_obs: float,
                gain: float = 1.0) -> np.ndarray:
    """The camera pose ``T`` (camera → world) turned about the camera centre and moved along ``n_w`` by ``gain`` (0..1)
    of what makes its predicted plane equal the measured ``(n_obs, d_obs)`` (camera frame)."""
    n_p, _ = plane_in_camera(T, n_w, d_w)
    a, b = n_obs, n_p  # axis = np.cross(n_obs, n_p), written out (the same products and differences; np.cross's
    # argument handling cost more than the rest of this function): the rotation taking n_obs to n_p (camera frame)
    axis = np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]], np.float64)
    s, c = float(np.linalg.norm(axis)), float(np.clip(n_obs @ n_p, -1.0, 1.0))
    out = np.array(T, dtype=np.float64)
    if s > 1e-12:
        angle = gain * np.arctan2(s, c)
        k = axis / s
        K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        Q = np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)
        out[:3, :3] = T[:3, :3] @ Q
    t = out[:3, 3]
    out[:3, 3] = t + gain * n_w * (d_obs - d_w - float(n_w @ t))
    return out
