"""A keyframe of the dense odometry: the sampled points of one RGB-D frame at every pyramid level, with what the
Gauss-Newton alignment needs precomputed (the photometric Jacobians of the inverse-compositional formulation and
the surface normals of the point-to-plane term).

Points are in the keyframe's camera frame (x right, y down, z forward; metres). Photometric points are valid-depth
pixels with a strong image gradient; geometric points are valid-depth pixels with a defined normal, taken on a
regular grid. Masked pixels (hands, parts) are never sampled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from tracker.odometry.rgbd_pyramid import PyramidLevel, image_gradients


@dataclass
class KeyframeLevel:
    """Samples of one pyramid level.

    * ``photo_points`` (N, 3) metres, ``photo_values`` (N,) grey levels, ``photo_jacobian`` (N, 6): derivative of
      the keyframe's grey value at the projection of ``exp(ξ)·p`` with respect to the twist ``ξ = [v, ω]``.
    * ``geo_points`` (M, 3) metres and ``geo_normals`` (M, 3) unit normals.
    """

    photo_points: np.ndarray
    photo_values: np.ndarray
    photo_jacobian: np.ndarray
    geo_points: np.ndarray
    geo_normals: np.ndarray


@dataclass
class Keyframe:
    """A reference frame: its ``levels`` (index = pyramid level), its ``pose`` in the world frame (4×4,
    camera → world) and the ``frame_index`` it was taken from."""

    levels: list[KeyframeLevel]
    pose: np.ndarray
    frame_index: int


@nb.njit(cache=True, nogil=True)
def points_and_normals(depth: np.ndarray, fx: float, fy: float, cx: float, cy: float) -> tuple[np.ndarray, np.ndarray]:
    """The point image (H×W×3 float32, metres, camera frame) of a depth image (float32 metres, NaN invalid) and its
    unit normals (cross product of central differences, oriented towards the camera; NaN on the border and where
    undefined), in one pass: exactly the values of ``Intrinsics.backproject(...).astype(float32)`` and of the numpy
    normals it replaced (float64 back-projection rounded to float32; float32 products, differences and sums in
    numpy's order; ``tests/test_odometry_kernels.py`` keeps that code as the reference), at a tenth of their time
    (a keyframe's 320×240 level cost 37 ms of numpy, most of a keyframe's 60)."""
    h, w = depth.shape
    pts = np.empty((h, w, 3), np.float32)
    for i in range(h):
        for j in range(w):
            z = np.float64(depth[i, j])
            pts[i, j, 0] = np.float32((j - cx) * z / fx)
            pts[i, j, 1] = np.float32((i - cy) * z / fy)
            pts[i, j, 2] = np.float32(z)
    nrm = np.full((h, w, 3), np.nan, np.float32)
    minus = np.float32(-1.0)
    for i in range(1, h - 1):
        for j in range(1, w - 1):
            a0 = pts[i, j + 1, 0] - pts[i, j - 1, 0]
            a1 = pts[i, j + 1, 1] - pts[i, j - 1, 1]
            a2 = pts[i, j + 1, 2] - pts[i, j - 1, 2]
            b0 = pts[i + 1, j, 0] - pts[i - 1, j, 0]
            b1 = pts[i + 1, j, 1] - pts[i - 1, j, 1]
            b2 = pts[i + 1, j, 2] - pts[i - 1, j, 2]
            c0 = a1 * b2 - a2 * b1
            c1 = a2 * b0 - a0 * b2
            c2 = a0 * b1 - a1 * b0
            norm = np.sqrt((c0 * c0 + c1 * c1) + c2 * c2)
            c0, c1, c2 = c0 / norm, c1 / norm, c2 / norm
            if (c0 * pts[i, j, 0] + c1 * pts[i, j, 1]) + c2 * pts[i, j, 2] > 0:
                c0, c1, c2 = c0 * minus, c1 * minus, c2 * minus
            nrm[i, j, 0] = c0
            nrm[i, j, 1] = c1
            nrm[i, j, 2] = c2
    return pts, nrm


def _subsample(idx: np.ndarray, n_max: int, rng: np.random.Generator) -> np.ndarray:
    if idx.size <= n_max:
        return idx
    return np.sort(rng.choice(idx, size=n_max, replace=False))


def make_keyframe_level(level: PyramidLevel, n_photo: int, n_geo: int, min_gradient: float,
                        rng: np.random.Generator) -> KeyframeLevel:
    """Sample a pyramid level (see the module docstring): at most ``n_photo`` photometric points with gradient
    magnitude ≥ ``min_gradient`` grey levels per pixel and at most ``n_geo`` geometric points."""
    intr = level.intrinsics
    pts, normals = points_and_normals(np.ascontiguousarray(level.depth, np.float32), float(intr.fx), float(intr.fy),
                                      float(intr.cx), float(intr.cy))
    gx, gy = image_gradients(level.gray)
    usable = np.isfinite(level.depth) & ~level.mask
    usable[:2, :] = usable[-2:, :] = False
    usable[:, :2] = usable[:, -2:] = False
    grad = np.hypot(gx, gy)

    photo = _subsample(np.flatnonzero(usable & (grad >= min_gradient)), n_photo, rng)
    p = pts.reshape(-1, 3)[photo].astype(np.float64)
    gxs, gys = gx.ravel()[photo].astype(np.float64), gy.ravel()[photo].astype(np.float64)
    z = p[:, 2]
    # d(grey)/d(point) through the pinhole projection, then d(point)/dξ = [I, -[p]x]
    jp = np.stack([gxs * intr.fx / z, gys * intr.fy / z, -(gxs * intr.fx * p[:, 0] + gys * intr.fy * p[:, 1]) / z**2],
                  axis=1)
    jac = np.concatenate([jp, np.cross(p, jp)], axis=1)

    geo_ok = usable & np.isfinite(normals[..., 0])
    geo = _subsample(np.flatnonzero(geo_ok), n_geo, rng)
    return KeyframeLevel(
        photo_points=p,
        photo_values=level.gray.ravel()[photo].astype(np.float64),
        photo_jacobian=jac,
        geo_points=pts.reshape(-1, 3)[geo].astype(np.float64),
        geo_normals=normals.reshape(-1, 3)[geo].astype(np.float64),
    )
