"""Pinhole camera intrinsics and projection (camera frame: x right, y down, z forward; metres, pixels)."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numba as nb
import numpy as np


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics of a W×H image. ``fx, fy`` focal lengths and ``cx, cy`` principal point in pixels.

    Pixel ``(u, v)`` (column, row; pixel centres at integer coordinates) of a camera-frame point
    ``(X, Y, Z)`` is ``u = fx X/Z + cx``, ``v = fy Y/Z + cy``.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValueError(f"intrinsics: image size must be positive, got {self.width}x{self.height}")
        vals = (self.fx, self.fy, self.cx, self.cy)
        if not all(np.isfinite(v) for v in vals):
            raise ValueError("intrinsics: fx, fy, cx, cy must be finite numbers")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"intrinsics: focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    @staticmethod
    def default(width: int = 640, height: int = 480) -> Intrinsics:
        """Kinect-like default: 640×480, fx = fy = 525 px, principal point at the image centre."""
        return Intrinsics(width, height, 525.0, 525.0, (width - 1) / 2.0, (height - 1) / 2.0)

    @property
    def K(self) -> np.ndarray:
        """3×3 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, factor: float) -> Intrinsics:
        """Intrinsics of the image resized by ``factor`` (e.g. 0.125 for 1/8 downsampling)."""
        w = max(1, int(round(self.width * factor)))
        h = max(1, int(round(self.height * factor)))
        return Intrinsics(
            w, h, self.fx * factor, self.fy * factor, (self.cx + 0.5) * factor - 0.5, (self.cy + 0.5) * factor - 0.5
        )

    def project(self, pts: np.ndarray) -> np.ndarray:
        """Pixels ``[N, 2]`` (u, v) of camera-frame points ``[N, 3]``."""
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
        return _project(pts, float(self.fx), float(self.fy), float(self.cx), float(self.cy))

    def backproject(self, u: np.ndarray, v: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Camera-frame points ``[..., 3]`` of pixels ``(u, v)`` at depth ``z`` metres."""
        u, v, z = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float), np.asarray(z, float))
        return np.stack([(u - self.cx) * z / self.fx, (v - self.cy) * z / self.fy, z], axis=-1)

    def depth_to_points(self, depth: np.ndarray) -> np.ndarray:
        """Back-project a depth image (metres, NaN missing) to an H×W×3 point image (NaN where missing)."""
        h, w = depth.shape
        v, u = np.mgrid[0:h, 0:w]
        return self.backproject(u, v, depth)

    def to_dict(self) -> dict:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict) -> Intrinsics:
        try:
            return Intrinsics(
                int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"]), float(d["cx"]), float(d["cy"])
            )
        except KeyError as exc:
            raise ValueError(f"intrinsics: missing field {exc.args[0]!r}") from exc
        except (TypeError, ValueError) as exc:
            raise ValueError(f"intrinsics: {exc}") from exc

    @staticmethod
    def load(path: str | Path) -> Intrinsics:
        return Intrinsics.from_dict(json.loads(Path(path).read_text()))


@nb.njit(cache=True, error_model="numpy")
def _project(pts: np.ndarray, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """:meth:`Intrinsics.project` per point, numpy's element-wise operations in its order (``fx · X / Z + cx``;
    IEEE division: Z = 0 gives ±inf or NaN as numpy does)."""
    out = np.empty((pts.shape[0], 2))
    for i in range(pts.shape[0]):
        z = pts[i, 2]
        out[i, 0] = fx * pts[i, 0] / z + cx
        out[i, 1] = fy * pts[i, 1] / z + cy
    return out
