"""The table plane as a constraint on the camera pose (odometry/table_constraint.py)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from tracker.geometry.camera import Intrinsics
from tracker.odometry.table_constraint import apply_plane, plane_in_camera, refit_plane

N_W = np.array([0.0, -0.8, -0.6])  # the world's table (the first camera frame): upward normal, offset
D_W = 0.5


def _pose(rotvec_deg, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.radians(rotvec_deg)).as_matrix()
    T[:3, 3] = t
    return T


def test_a_measured_plane_fixes_tilt_and_height_and_leaves_the_rest():
    """The estimate is tilted by 1° and 5 mm too high, and turned by 2° about the normal / slid 1 cm along the table.
    The plane seen from the true pose corrects exactly the first two; the turn and slide along the table stay."""
    truth = _pose([0.5, -1.0, 0.3], [0.01, 0.02, -0.01])
    n_c, d_c = plane_in_camera(truth, N_W, D_W)
    slide = np.cross(N_W, [1.0, 0.0, 0.0])
    slide /= np.linalg.norm(slide)
    yaw = _pose(2.0 * N_W, 0.01 * slide)  # world-frame turn about the normal (through the origin) and slide
    tilt = _pose([1.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    est = yaw @ truth @ tilt
    est[:3, 3] += 0.005 * N_W
    fixed = apply_plane(est, N_W, D_W, n_c, d_c)
    n_f, d_f = plane_in_camera(fixed, N_W, D_W)
    assert np.allclose(n_f, n_c, atol=1e-9) and abs(d_f - d_c) < 1e-9
    before = plane_in_camera(est, N_W, D_W)
    assert np.degrees(np.arccos(before[0] @ n_c)) > 0.9 and abs(before[1] - d_c) > 0.004
    # what the plane cannot see is left: the turn about the normal remains ~2°, the slide ~1 cm
    R_err = truth[:3, :3].T @ fixed[:3, :3]
    assert 1.5 < np.degrees(np.arccos((np.trace(R_err) - 1) / 2)) < 2.5
    assert np.linalg.norm(fixed[:3, 3] - truth[:3, 3]) > 0.005


def test_refit_plane_ignores_what_stands_on_the_table_and_masked_pixels():
    K = Intrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
    n, d = np.array([0.0, -0.8, -0.6]), 0.5
    v, u = np.mgrid[0:480, 0:640].astype(np.float64)
    ray = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u)], axis=-1)
    depth = (-d / (ray @ n)).astype(np.float32)
    depth[depth <= 0] = np.nan
    depth[200:280, 300:380] -= 0.03  # a part standing 2–3 cm out of the plane
    depth[0:100, :] = 0.3  # a hand over the top rows, masked
    mask = np.zeros((480, 640), bool)
    mask[0:100, :] = True
    guess_n = Rotation.from_rotvec(np.radians([0.3, 0.0, 0.0])).as_matrix() @ n  # a slightly wrong prediction
    fit = refit_plane(depth, K, guess_n, d + 0.002, mask)
    assert fit is not None
    assert np.degrees(np.arccos(min(1.0, fit[0] @ n))) < 0.01 and abs(fit[1] - d) < 1e-4
    assert refit_plane(depth, K, n, d, np.ones((480, 640), bool)) is None  # everything masked: no measurement
