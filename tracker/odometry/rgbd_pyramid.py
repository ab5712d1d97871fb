"""Image pyramids of one RGB-D frame for the dense odometry.

Level ``l`` halves the image ``l`` times by 2×2 block averaging (so its intrinsics are
``Intrinsics.scaled(0.5**l)``). Grey values are float32 0..255; depth is float32 metres with NaN where the
sensor gave nothing; a depth block is valid only when all four of its pixels are and their spread is below
``MAX_BLOCK_SPREAD`` of their mean (blocks across an occlusion edge become NaN instead of mixing surfaces).
Masks (True = exclude: hands, moving parts) are max-pooled: a block is masked when any of its pixels is.
Camera frame: x right, y down, z forward.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tracker.geometry.camera import Intrinsics

MAX_BLOCK_SPREAD = 0.02
"""Largest (max − min) / mean depth of a 2×2 block kept when downsampling depth."""


@dataclass
class PyramidLevel:
    """One pyramid level: ``gray`` (H×W float32 0..255), ``depth`` (H×W float32 metres, NaN invalid),
    ``mask`` (H×W bool, True = excluded) and the level's ``intrinsics``."""

    gray: np.ndarray
    depth: np.ndarray
    mask: np.ndarray
    intrinsics: Intrinsics


def to_gray(rgb: np.ndarray) -> np.ndarray:
    """Luminance of an RGB uint8 image as float32 0..255."""
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)


def half_depth(depth: np.ndarray) -> np.ndarray:
    """2×2 block mean of a depth image (NaN where a block is incomplete or spans an edge)."""
    h, w = depth.shape[0] // 2 * 2, depth.shape[1] // 2 * 2
    a, b, c, d = depth[0:h:2, 0:w:2], depth[0:h:2, 1:w:2], depth[1:h:2, 0:w:2], depth[1:h:2, 1:w:2]
    mean = (a + b + c + d) * 0.25  # NaN if any of the four is NaN
    spread = np.maximum(np.maximum(a, b), np.maximum(c, d)) - np.minimum(np.minimum(a, b), np.minimum(c, d))
    with np.errstate(invalid="ignore"):
        mean[spread > MAX_BLOCK_SPREAD * mean] = np.nan
    return mean.astype(np.float32)


def half_mask(mask: np.ndarray) -> np.ndarray:
    """2×2 max-pool of a boolean mask."""
    h, w = mask.shape[0] // 2 * 2, mask.shape[1] // 2 * 2
    return mask[0:h:2, 0:w:2] | mask[0:h:2, 1:w:2] | mask[1:h:2, 0:w:2] | mask[1:h:2, 1:w:2]


def build_pyramid(rgb: np.ndarray, depth: np.ndarray, intrinsics: Intrinsics, n_levels: int,
                  mask: np.ndarray | None = None) -> list[PyramidLevel]:
    """Levels 0..n_levels-1 of an RGB uint8 image and its registered depth (metres, NaN invalid)."""
    h, w = depth.shape
    gray = to_gray(rgb)
    m = np.zeros((h, w), bool) if mask is None else np.asarray(mask, bool)
    d = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan).astype(np.float32)
    levels = [PyramidLevel(gray, d, m, intrinsics)]
    for lv in range(1, n_levels):
        prev = levels[-1]
        ph, pw = prev.depth.shape
        g = cv2.resize(prev.gray[: ph // 2 * 2, : pw // 2 * 2], (pw // 2, ph // 2), interpolation=cv2.INTER_AREA)
        levels.append(PyramidLevel(g, half_depth(prev.depth), half_mask(prev.mask), intrinsics.scaled(0.5**lv)))
    return levels


def depth_normals(points: np.ndarray) -> np.ndarray:
    """Unit normals (H×W×3, NaN where undefined) of a point image by the cross product of central differences,
    oriented towards the camera."""
    n = np.full(points.shape, np.nan, np.float32)
    dx = points[1:-1, 2:] - points[1:-1, :-2]
    dy = points[2:, 1:-1] - points[:-2, 1:-1]
    c = np.cross(dx, dy)
    norm = np.linalg.norm(c, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = c / norm
    flip = np.sum(c * points[1:-1, 1:-1], axis=-1) > 0
    c[flip] *= -1.0
    n[1:-1, 1:-1] = c
    return n


def image_gradients(gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Central-difference gradients ``(d/du, d/dv)`` of a grey image (grey levels per pixel)."""
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3, scale=1.0 / 8.0)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3, scale=1.0 / 8.0)
    return gx, gy
