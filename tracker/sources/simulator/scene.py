"""The simulated scene: camera placement above the table, the table (with a procedural wood texture),
the floor around it, and the light.

Table frame (as everywhere in the project): origin where the camera's optical axis meets the table
plane, y = upward table normal, x = camera x projected on the table, z = x × y (towards the user /
the camera side). The camera sits at distance ``distance`` from the table centre, on the user's side,
looking down at ``elevation_deg`` below the horizontal, without roll.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from tracker.geometry.camera import Intrinsics
from tracker.geometry.pose import Pose
from tracker.sources.simulator.rasterizer import cast_background

TABLE_X = (-0.75, 0.75)
"""Table extent along the table frame's x axis, metres."""
TABLE_Z = (-0.60, 0.55)
"""Table extent along z (negative: away from the user), metres."""
FLOOR_DROP = 0.74
"""Floor lies this far below the table top, metres."""

LIGHT_DIR_TABLE = np.array([-0.35, 1.0, 0.45]) / np.linalg.norm([-0.35, 1.0, 0.45])
"""Unit direction towards the (directional) light in the table frame: above, left, user side."""
AMBIENT = 0.42
DIFFUSE = 0.62


@dataclass(frozen=True)
class CameraPlacement:
    """Camera ``distance`` (metres) from the table centre and ``elevation_deg`` below the horizontal."""

    distance: float
    elevation_deg: float

    def __post_init__(self) -> None:
        if not 0.2 <= self.distance <= 3.0:
            raise ValueError(f"camera distance must be within 0.2–3 m, got {self.distance}")
        if not 10.0 <= self.elevation_deg <= 90.0:
            raise ValueError(f"camera elevation must be within 10–90°, got {self.elevation_deg}")

    def camera_to_table(self) -> Pose:
        """Pose of the camera in the table frame."""
        th = np.radians(self.elevation_deg)
        c = self.distance * np.array([0.0, np.sin(th), np.cos(th)])
        x = np.array([1.0, 0.0, 0.0])
        z = -c / np.linalg.norm(c)
        y = np.cross(z, x)
        return Pose.from_rt(np.stack([x, y, z], axis=1), c)

    def table_to_camera(self) -> Pose:
        """Pose of the table frame in the camera frame (maps table-frame points to camera-frame points)."""
        return self.camera_to_table().inverse()

    def table_plane(self) -> tuple[np.ndarray, float]:
        """``(n, d)`` with ``n·p + d = 0`` for camera-frame points on the table, ``n`` the upward unit normal."""
        T = self.table_to_camera()
        n = T.R[:, 1]
        d = -float(n @ T.t)
        return n, d


@dataclass
class Background:
    """Static background images of one camera: shaded colour (float32 0..255, H×W×3), noise-free depth
    (float32 metres, ``inf`` where nothing is in range), |cos| incidence (float32) and the table mask (bool)."""

    color: np.ndarray
    depth: np.ndarray
    cosang: np.ndarray
    table: np.ndarray


def _value_noise(rng: np.random.Generator, shape: tuple[int, int], cells: tuple[int, int]) -> np.ndarray:
    """Smooth noise in [-1, 1] of ``shape`` (rows, cols) from a random grid of ``cells`` resized bicubically."""
    grid = rng.uniform(-1.0, 1.0, size=cells).astype(np.float32)
    return cv2.resize(grid, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)


@lru_cache(maxsize=2)
def wood_texture(seed: int = 1234, texels_per_m: float = 1200.0) -> np.ndarray:
    """Procedural wood-like RGB texture (float32 0..255) covering the table; rows = z, cols = x.

    Planks 0.14 m wide run along x with fine grain lines distorted by smooth noise, plus per-plank tint.
    The table is the same piece of furniture in every scenario, so the texture is made once (cached).
    """
    rng = np.random.default_rng(seed)
    w = int((TABLE_X[1] - TABLE_X[0]) * texels_per_m)
    h = int((TABLE_Z[1] - TABLE_Z[0]) * texels_per_m)
    zz = (np.arange(h, dtype=np.float32) / texels_per_m)[:, None]
    xx = (np.arange(w, dtype=np.float32) / texels_per_m)[None, :]
    warp = 0.012 * _value_noise(rng, (h, w), (12, 40)) + 0.003 * _value_noise(rng, (h, w), (60, 200))
    grain = np.sin(2 * np.pi * (zz + warp + 0.002 * np.sin(xx * 3.0)) * 180.0)
    grain = 0.5 + 0.5 * grain**3
    plank = np.floor(zz / 0.14).astype(int)
    n_planks = int(plank.max()) + 1
    tint = rng.uniform(-0.07, 0.07, size=n_planks).astype(np.float32)
    shade = 1.0 + tint[plank] - 0.10 * grain + 0.04 * _value_noise(rng, (h, w), (8, 20))
    seam = (np.abs(zz / 0.14 - np.round(zz / 0.14)) * 0.14 < 0.0012).astype(np.float32)
    shade = shade * (1.0 - 0.35 * seam)
    base = np.array([176.0, 128.0, 84.0], np.float32)
    return np.clip(shade[..., None] * base, 0, 255).astype(np.float32)


def render_background(intr: Intrinsics, cam: CameraPlacement, rng: np.random.Generator) -> Background:
    """Ray-cast the table (textured) and the floor for every pixel of the camera."""
    h, w = intr.height, intr.width
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    d = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], axis=-1)
    c2t = cam.camera_to_table()
    dt = d @ c2t.R.T  # ray directions in the table frame (not normalised; z_cam component = 1)
    ct = c2t.t
    light = LIGHT_DIR_TABLE
    depth = np.full((h, w), np.inf, np.float32)
    cosang = np.ones((h, w), np.float32)
    color = np.zeros((h, w, 3), np.float32)
    dn = np.linalg.norm(d, axis=-1)

    # floor first, the table overwrites it
    with np.errstate(divide="ignore", invalid="ignore"):
        tf = (-FLOOR_DROP - ct[1]) / dt[..., 1]
    floor = tf > 0
    floor_tex = 0.5 * _value_noise(rng, (h, w), (30, 40)) + 0.5 * _value_noise(rng, (h, w), (120, 160))
    depth[floor] = tf[floor]
    cosang[floor] = np.abs(dt[..., 1][floor]) / dn[floor]
    grey = np.array([120.0, 118.0, 112.0], np.float32)
    fshade = (AMBIENT * 0.8 + DIFFUSE * 0.8 * light[1]) * (1.0 + 0.08 * floor_tex)
    color[floor] = fshade[floor][:, None] * grey

    with np.errstate(divide="ignore", invalid="ignore"):
        tt = -ct[1] / dt[..., 1]
    p = ct + tt[..., None] * dt
    on_table = (tt > 0) & (p[..., 0] > TABLE_X[0]) & (p[..., 0] < TABLE_X[1])
    on_table &= (p[..., 2] > TABLE_Z[0]) & (p[..., 2] < TABLE_Z[1])
    tex = wood_texture()
    tpm = tex.shape[1] / (TABLE_X[1] - TABLE_X[0])
    map_x = ((p[..., 0] - TABLE_X[0]) * tpm).astype(np.float32)
    map_y = ((p[..., 2] - TABLE_Z[0]) * tpm).astype(np.float32)
    albedo = cv2.remap(tex, map_x, map_y, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    # a broad spot of light centred slightly left of the table centre
    spot = np.exp(-((p[..., 0] + 0.1) ** 2 + (p[..., 2] + 0.05) ** 2) / (2 * 0.45**2))
    tshade = (AMBIENT + DIFFUSE * light[1]) * (0.85 + 0.15 * spot)
    color[on_table] = albedo[on_table] * tshade[on_table][:, None]
    depth[on_table] = tt[on_table]
    cosang[on_table] = np.abs(dt[..., 1][on_table]) / dn[on_table]
    return Background(color=color, depth=depth, cosang=cosang, table=on_table)


FLOOR_EXTENT = 16.0
"""Side of the (repeated) square floor texture of :class:`BackgroundCaster`, metres."""
FLOOR_TEXELS_PER_M = 100.0


class BackgroundCaster:
    """Ray-casts the table and the floor for any camera pose (the moving camera; see
    :func:`tracker.sources.simulator.rasterizer.cast_background`). Unlike :func:`render_background`, whose floor
    noise is drawn in image space for the one fixed camera, the floor texture here is fixed in the table frame
    (drawn once from ``rng``), so it moves consistently with the scene. Shading is the same as there."""

    def __init__(self, intr: Intrinsics, rng: np.random.Generator) -> None:
        self.intr = intr
        n = int(FLOOR_EXTENT * FLOOR_TEXELS_PER_M)
        floor = 0.5 * _value_noise(rng, (n, n), (160, 160)) + 0.5 * _value_noise(rng, (n, n), (640, 640))
        self.floor_tex = np.ascontiguousarray(floor[..., None], dtype=np.float32)
        self.tex = wood_texture()
        self.tpm = self.tex.shape[1] / (TABLE_X[1] - TABLE_X[0])
        light = LIGHT_DIR_TABLE
        self.table_shade = float(AMBIENT + DIFFUSE * light[1])
        self.floor_shade = float(AMBIENT * 0.8 + DIFFUSE * 0.8 * light[1])
        self.grey = np.array([120.0, 118.0, 112.0])
        self.table_ext = np.array([TABLE_X[0], TABLE_X[1], TABLE_Z[0], TABLE_Z[1]])
        self.floor_ext = np.array([-FLOOR_EXTENT / 2, -FLOOR_EXTENT / 2])
        self.spot = np.array([-0.1, -0.05, 0.45])

    def render(self, camera_to_table: Pose, depth: np.ndarray, cosang: np.ndarray, color: np.ndarray,
               table: np.ndarray) -> None:  # fmt: skip
        """Overwrite the buffers (H×W float32 depth / cosang, H×W×3 float32 colour, H×W bool table mask) with
        the background seen from ``camera_to_table`` (the camera's pose in the table frame)."""
        i = self.intr
        cast_background(depth, cosang, color, table, i.fx, i.fy, i.cx, i.cy, np.ascontiguousarray(camera_to_table.R),
                        np.asarray(camera_to_table.t, float), self.tex, self.tpm, self.table_ext, self.floor_tex,
                        FLOOR_TEXELS_PER_M, self.floor_ext, FLOOR_DROP, self.grey, self.table_shade,
                        self.floor_shade, self.spot)  # fmt: skip
