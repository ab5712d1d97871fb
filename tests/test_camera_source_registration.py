"""Depth-to-colour registration on synthetic scenes with known geometry."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tracker.geometry.camera import Intrinsics
from tracker.sources.depth_registration import register_depth

COLOR = Intrinsics(160, 120, 150.0, 151.0, 79.5, 59.5)
DEPTH = Intrinsics(128, 96, 110.0, 110.0, 63.0, 48.5)


def _depth_to_color() -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [1.0, -3.0, 0.5], degrees=True).as_matrix()
    T[:3, 3] = [0.025, 0.002, -0.003]
    return T


def render(intr: Intrinsics, cam_to_color: np.ndarray) -> np.ndarray:
    """Analytic depth (camera z) of the scene seen by a camera with pose ``cam_to_color`` in the colour frame.

    Scene (colour frame, metres): a tilted plane n·p = 0.9 and a 10 × 6 cm square facing the camera at z = 0.6.
    """
    v, u = np.mgrid[0 : intr.height, 0 : intr.width].astype(np.float64)
    rays = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], axis=-1)
    R, o = cam_to_color[:3, :3], cam_to_color[:3, 3]
    d = rays @ R.T  # ray directions in the colour frame, scaled so that camera z = s
    n = np.array([0.0, -0.35, 1.0])
    n /= np.linalg.norm(n)
    s_plane = (0.9 - n @ o) / (d @ n)
    s_patch = (0.6 - o[2]) / d[..., 2]
    p = o + s_patch[..., None] * d
    on_patch = (np.abs(p[..., 0]) < 0.05) & (np.abs(p[..., 1]) < 0.03)
    z = np.where(on_patch, np.minimum(s_patch, s_plane), s_plane)
    return z.astype(np.float32)


def test_identity_registration_is_exact():
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 2.0, size=(96, 128)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.2] = np.nan
    out = register_depth(depth, DEPTH, DEPTH, np.eye(4))
    np.testing.assert_array_equal(out, depth)


def test_registration_matches_analytic_colour_depth():
    T = _depth_to_color()
    depth = render(DEPTH, T)
    expected = render(COLOR, np.eye(4))
    out = register_depth(depth, DEPTH, COLOR, T)
    assert out.shape == (120, 160) and out.dtype == np.float32
    # the colour pixels that the depth camera also sees (its field of view is narrower): away from the border
    inner = np.zeros_like(out, dtype=bool)
    inner[20:100, 25:135] = True
    assert np.isfinite(out[inner]).mean() > 0.99  # the splat leaves no holes
    err = np.abs(out - expected)[inner & np.isfinite(out)]
    # the step at the square's border moves by parallax; everywhere else the depth agrees to millimetres
    assert np.median(err) < 0.001
    assert np.mean(err < 0.005) > 0.97
    # the near square is at 0.6 m in the colour image where it should be: z-buffer kept the nearest surface
    v, u = np.mgrid[0:120, 0:160]
    x = (u - COLOR.cx) / COLOR.fx * 0.6
    y = (v - COLOR.cy) / COLOR.fy * 0.6
    patch_inner = (np.abs(x) < 0.045) & (np.abs(y) < 0.025)
    np.testing.assert_allclose(out[patch_inner], 0.6, atol=1e-4)
    outside = (np.abs(x) > 0.06) | (np.abs(y) > 0.04)
    assert np.nanmin(out[outside & inner]) > 0.65


def test_registration_z_buffer_keeps_nearest():
    # two depth pixels land on the same colour pixel: the nearer one wins regardless of order
    intr = Intrinsics(2, 1, 100.0, 100.0, 0.5, 0.0)
    color = Intrinsics(1, 1, 1.0, 1.0, 0.0, 0.0)  # one tiny colour pixel sees everything near the axis
    for d in ([1.0, 2.0], [2.0, 1.0]):
        out = register_depth(np.array([d], np.float32), intr, color, np.eye(4))
        assert out[0, 0] == pytest.approx(1.0)


def test_registration_translation_shifts_pixels():
    # a fronto-parallel wall at 1 m seen by a depth camera 10 cm to the right of the colour camera
    intr = Intrinsics(40, 30, 50.0, 50.0, 19.5, 14.5)
    T = np.eye(4)
    T[0, 3] = 0.1  # depth-frame point + 0.1 m in x = colour-frame point
    depth = np.full((30, 40), np.nan, np.float32)
    depth[10:20, 10:20] = 1.0
    out = register_depth(depth, intr, intr, T)
    # shift of fx * 0.1 / 1.0 = 5 px to the right
    np.testing.assert_array_equal(np.isfinite(out[10:20]).any(axis=0).nonzero()[0], np.arange(15, 25))
    np.testing.assert_allclose(out[10:20, 15:25], 1.0)


def test_registration_input_checks():
    with pytest.raises(ValueError, match="depth intrinsics say 128x96"):
        register_depth(np.zeros((10, 10), np.float32), DEPTH, COLOR, np.eye(4))
    with pytest.raises(ValueError, match="4x4"):
        register_depth(np.zeros((96, 128), np.float32), DEPTH, COLOR, np.eye(3))
