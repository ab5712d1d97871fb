"""A keyframe of the dense odometry: the sampled points of one RGB-D frame at every pyramid level, with what the
Gauss-Newton alignment needs precomputed (the photometric Jacobians of the inverse-compositional formulation and
the surface normals of the point-to-plane term).

Points are in the keyframe's camera frame (x right, y down, z forward; metres). Photometric points are valid-depth
pixels with a strong image gradient; geometric points are valid-depth pixels with a defined normal, taken on a
regular grid. Masked pixels (hands, parts) are never sampled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tracker.odometry.rgbd_pyramid import PyramidLevel, depth_normals, image_gradients


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


def _subsample(idx: np.ndarray, n_max: int, rng: np.random.Generator) -> np.ndarray:
    if idx.size <= n_max:
        return idx
    return np.sort(rng.choice(idx, size=n_max, replace=False))


def make_keyframe_level(level: PyramidLevel, n_photo: int, n_geo: int, min_gradient: float,
                        rng: np.random.Generator) -> KeyframeLevel:
    """Sample a pyramid level (see the module docstring): at most ``n_photo`` photometric points with gradient
    magnitude ≥ ``min_gradient`` grey levels per pixel and at most ``n_geo`` geometric points."""
    intr = level.intrinsics
    h, w = level.depth.shape
    v, u = np.mgrid[0:h, 0:w]
    pts = intr.backproject(u, v, level.depth).astype(np.float32)
    normals = depth_normals(pts)
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
