"""Table plane detection: synthetic planes with known answers, real desk frames, error cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from shared_data import REAL, needs_shared

from tracker.geometry.camera import Intrinsics
from tracker.geometry.pose import Pose
from tracker.perception.table_plane import (
    TableMonitor,
    TableNotFoundError,
    TablePlane,
    detect_table,
    fit_plane_svd,
    table_changed,
)


def plane_from_camera_tilt(tilt_deg: float, height: float, roll_deg: float = 0.0) -> tuple[np.ndarray, float]:
    """Upward normal/offset of a table seen by a camera ``height`` m above it, pitched down by ``tilt_deg``
    from horizontal (90° = straight down) and rolled by ``roll_deg``."""
    t, r = math.radians(tilt_deg), math.radians(roll_deg)
    # world up expressed in the camera frame for a camera pitched down by t (y down, z forward)
    n = np.array([0.0, -math.cos(t), -math.sin(t)])
    c, s = math.cos(r), math.sin(r)
    n = np.array([c * n[0] - s * n[1], s * n[0] + c * n[1], n[2]])
    return n / np.linalg.norm(n), height


def render_plane_depth(
    intr: Intrinsics,
    n: np.ndarray,
    d: float,
    rng: np.random.Generator,
    boxes: list[tuple[int, int, int, int, float]] = (),
    noise: float = 0.001,
    holes: float = 0.02,
) -> np.ndarray:
    """Depth (metres, NaN missing) of plane n·p + d = 0 with raised rectangular patches (u, v, w, h, height m)
    standing in for objects, Gaussian noise growing with z², and random missing pixels."""
    v, u = np.mgrid[0 : intr.height, 0 : intr.width].astype(np.float64)
    rays = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u)], axis=-1)
    nr = rays @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        z = -d / nr
        for bu, bv, bw, bh, hgt in boxes:
            sl = (slice(bv, bv + bh), slice(bu, bu + bw))
            z[sl] = -(d - hgt) / nr[sl]
    z[(z <= 0) | (z > 6) | ~np.isfinite(z)] = np.nan
    z = z + rng.normal(0.0, 1.0, z.shape) * noise * np.nan_to_num(z) ** 2
    z[rng.random(z.shape) < holes] = np.nan
    return z.astype(np.float32)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(float(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


@pytest.mark.parametrize("tilt,height,roll", [(45.0, 0.6, 0.0), (60.0, 0.8, 8.0), (30.0, 0.5, -5.0)])
def test_synthetic_plane_with_objects(tilt, height, roll):
    rng = np.random.default_rng(int(tilt))
    intr = Intrinsics.default()
    n, d = plane_from_camera_tilt(tilt, height, roll)
    boxes = [(200, 250, 40, 40, 0.036), (400, 300, 50, 45, 0.036), (300, 150, 30, 60, 0.07)]
    depth = render_plane_depth(intr, n, d, rng, boxes)
    plane = detect_table(depth, intr)
    assert angle_deg(plane.normal, n) < 0.5
    assert abs(plane.offset - d) < 0.003
    assert plane.inlier_fraction > 0.8
    assert plane.residual_rms < 0.005
    assert len(plane.outline) >= 3


def test_straight_down_camera():
    rng = np.random.default_rng(3)
    intr = Intrinsics.default()
    n, d = np.array([0.0, 0.0, -1.0]), 0.7
    depth = render_plane_depth(intr, n, d, rng, [(300, 200, 40, 40, 0.036)])
    plane = detect_table(depth, intr)
    assert angle_deg(plane.normal, n) < 0.5
    assert abs(plane.offset - d) < 0.003


def test_table_partly_visible_beside_a_wall():
    """A wall (vertical plane) above the table must not be picked up nor merged through the crease."""
    rng = np.random.default_rng(5)
    intr = Intrinsics.default()
    n, d = plane_from_camera_tilt(35.0, 0.6)
    depth = render_plane_depth(intr, n, d, rng)
    wall_n = np.array([0.0, 0.0, -1.0])  # wall facing the camera 1.2 m ahead, occupies the upper rows
    v, u = np.mgrid[0:480, 0:640].astype(np.float64)
    z_wall = np.full(u.shape, 1.2)
    nearer = np.nan_to_num(depth, nan=9.0) > z_wall
    depth[nearer & (v < 200)] = z_wall[nearer & (v < 200)]
    plane = detect_table(depth, intr)
    assert angle_deg(plane.normal, n) < 0.5, plane.normal
    assert angle_deg(plane.normal, wall_n) > 30


def test_orientation_height_and_frame():
    rng = np.random.default_rng(11)
    intr = Intrinsics.default()
    n, d = plane_from_camera_tilt(50.0, 0.6, 10.0)
    plane = detect_table(render_plane_depth(intr, n, d, rng), intr)
    # camera centre is above the table; a point below the table has negative height
    assert plane.height(np.zeros(3)) == pytest.approx(plane.offset)
    assert plane.offset > 0
    below = plane.origin() - 0.05 * plane.normal
    assert plane.height(below) == pytest.approx(-0.05, abs=1e-9)
    T = plane.table_to_camera()
    R = T.R
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-9) and np.linalg.det(R) == pytest.approx(1.0)
    assert np.allclose(R[:, 1], plane.normal)  # table y = up normal
    assert abs(R[:, 0] @ plane.normal) < 1e-9 and R[0, 0] > 0.9  # x = camera x projected
    assert np.allclose(R[:, 2], np.cross(R[:, 0], R[:, 1]))
    # origin on the plane and on the optical axis
    assert plane.height(T.t) == pytest.approx(0.0, abs=1e-9)
    assert abs(T.t[0]) < 1e-9 and abs(T.t[1]) < 1e-9 and T.t[2] > 0
    # a point 5 cm above the table origin, in table coordinates (0, 0.05, 0)
    p = T.transform_points(np.array([[0.0, 0.05, 0.0]]))
    assert plane.height(p)[0] == pytest.approx(0.05)


def test_no_valid_depth_raises_clear_error():
    intr = Intrinsics.default(64, 48)
    with pytest.raises(TableNotFoundError, match="no valid pixels"):
        detect_table(np.full((48, 64), np.nan, np.float32), intr)
    with pytest.raises(TableNotFoundError, match="no valid pixels"):
        detect_table(np.zeros((48, 64), np.float32), intr)
    assert issubclass(TableNotFoundError, ValueError)


def test_no_smooth_region_and_size_mismatch():
    rng = np.random.default_rng(0)
    intr = Intrinsics.default(64, 48)
    rough = rng.uniform(0.5, 3.0, (48, 64)).astype(np.float32)
    with pytest.raises(TableNotFoundError, match="no smooth depth region"):
        detect_table(rough, intr)
    with pytest.raises(TableNotFoundError, match="64x48"):
        detect_table(np.ones((40, 40), np.float32), intr)


def test_changed_and_monitor():
    rng = np.random.default_rng(2)
    intr = Intrinsics.default(320, 240)
    n, d = plane_from_camera_tilt(45.0, 0.6)
    a = TablePlane(n, d)
    assert not table_changed(a, TablePlane(n, d + 0.002))
    assert table_changed(a, TablePlane(n, d + 0.05))
    n2, _ = plane_from_camera_tilt(50.0, 0.6)
    assert table_changed(a, TablePlane(n2, d))
    mon = TableMonitor(intr, every=2)
    assert mon.update(render_plane_depth(intr, n, d, rng)) is False and mon.plane is not None
    assert mon.update(render_plane_depth(intr, n2, d, rng)) is False  # not due yet
    assert mon.update(render_plane_depth(intr, n2, d, rng)) is True  # re-detected: camera moved
    assert angle_deg(mon.plane.normal, n2) < 0.5


def test_dict_round_trip_and_sign_normalisation():
    p = TablePlane(np.array([0.0, 2.0, 0.0]), -1.0, 0.9, 0.002, np.array([[1, 2], [3, 4], [5, 6]]), 100)
    assert np.allclose(p.normal, [0, -1, 0]) and p.offset == pytest.approx(0.5)
    q = TablePlane.from_dict(p.to_dict())
    assert np.allclose(q.normal, p.normal) and q.offset == p.offset and q.outline.shape == (3, 2)
    with pytest.raises(ValueError, match="missing field 'offset'"):
        TablePlane.from_dict({"normal": [0, -1, 0]})
    with pytest.raises(ValueError):
        TablePlane(np.zeros(3), 1.0)


def test_centred_points_equal_numpys_mean():
    """The compiled centring of fit_plane_svd gives numpy's mean and differences exactly (seeded point sets of
    several sizes and scales, float32-rounded ones among them)."""
    from tracker.perception.table_plane import _centred

    rng = np.random.default_rng(3)
    for trial in range(60):
        n = int(rng.integers(3, 12000))
        pts = rng.normal(size=(n, 3)) * rng.uniform(0.01, 3.0) + rng.normal(size=3)
        if trial % 2:
            pts = pts.astype(np.float32).astype(np.float64)
        c, q = _centred(pts)
        assert np.array_equal(c, pts.mean(axis=0)) and np.array_equal(q, pts - pts.mean(axis=0))


def test_fit_plane_svd_exact():
    rng = np.random.default_rng(1)
    n = np.array([0.2, -0.9, -0.3])
    n /= np.linalg.norm(n)
    pts = rng.normal(size=(200, 3))
    pts -= np.outer(pts @ n + 0.5, n)
    m, d = fit_plane_svd(pts)
    assert angle_deg(m, n) < 1e-6 and d == pytest.approx(0.5)
    assert isinstance(Pose.identity(), Pose)


def _real_depth(name: str, index: int = 0):
    from tracker.sources.recording import RecordingSource

    src = RecordingSource(REAL / name)
    return src.read(index)


@needs_shared
def test_real_visp_desk():
    f = _real_depth("visp-cube-desk")
    plane = detect_table(f.depth, f.intrinsics)
    assert plane.inlier_fraction > 0.75
    assert plane.residual_rms < 0.008
    assert plane.normal[1] < -0.5  # up in the image (camera looks down at the desk)
    assert 0.1 < plane.offset < 1.0  # camera a few tens of cm above the desk
    # the cube (about 4.2 cm) stands on the desk: the depth at the image centre region is above the plane
    pts = f.intrinsics.depth_to_points(f.depth)
    h = plane.height(pts[280:320, 330:420].reshape(-1, 3))
    assert np.nanmedian(h) > 0.01


@needs_shared
def test_real_tum_desk_horizontal_surface():
    f = _real_depth("tum-desk")
    plane = detect_table(f.depth, f.intrinsics)
    # a horizontal surface (desk or floor) seen by a camera pitched down: normal up in the image and
    # toward the camera, not the vertical panel behind the desk
    assert plane.normal[1] < -0.7 and plane.normal[2] < 0
    assert plane.inlier_fraction > 0.4 and plane.residual_rms < 0.01
    assert 0.5 < plane.offset < 2.5


@needs_shared
def test_inspect_table_cli(capsys):
    import json

    from app.cli import main

    assert main(["inspect", "table", str(REAL / "visp-cube-desk"), "--frame", "2"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) >= {"normal", "offset", "inlier_fraction", "residual_rms"}
    assert abs(np.linalg.norm(out["normal"]) - 1) < 1e-9 and out["offset"] > 0
    # the jenga recording has no depth: a clear error and exit status 1
    assert main(["inspect", "table", str(REAL / "jenga")]) == 1
    assert "no valid pixels" in capsys.readouterr().err
    assert main(["inspect", "table", str(REAL / "visp-cube-desk"), "--frame", "99"]) == 1
    assert "out of range" in capsys.readouterr().err


@pytest.mark.parametrize("scenario,seed,index", [("static", 3, 0), ("guess-2", 7, 200)])
def test_simulated_table_against_truth(scenario, seed, index):
    from tracker.sources.simulator import SimulatedTable

    src = SimulatedTable(scenario, seed=seed)
    f = src.render(index)
    n_true, d_true = src.table_plane
    plane = detect_table(f.depth, f.intrinsics)
    assert angle_deg(plane.normal, np.asarray(n_true)) < 0.5
    assert abs(plane.offset - d_true) < 0.003
    # the table frame matches the simulator's (same definition)
    T, T_true = plane.table_to_camera(), src.table_to_camera
    assert np.linalg.norm(T.t - T_true.t) < 0.01
    assert math.degrees(T.rotation_error(T_true)) < 0.5


def test_plane_distance_image_equals_the_back_projected_points_distance():
    """The outline's per-pixel plane distance (ray · normal form, float32) agrees with back-projecting every pixel
    and taking ``n · p + d`` (float64) to float32 precision, NaN where the depth is missing."""
    from tracker.perception.table_plane import plane_distance

    intr = Intrinsics.default(160, 120)
    rng = np.random.default_rng(4)
    n, d = plane_from_camera_tilt(50.0, 0.6, 7.0)
    depth = render_plane_depth(intr, n, d, rng, boxes=[(40, 30, 20, 20, 0.05)])
    got = plane_distance(depth, intr, n, d)
    want = intr.depth_to_points(depth.astype(np.float64)) @ n + d
    assert got.dtype == np.float32 and got.shape == depth.shape
    assert np.array_equal(np.isnan(got), np.isnan(depth))
    ok = ~np.isnan(depth)
    assert np.max(np.abs(got[ok] - want[ok])) < 2e-6
    assert np.nanmin(np.abs(got[35:45, 45:55])) > 0.03  # the raised box is off the plane, the table on it
    assert np.median(np.abs(got[ok])) < 0.005
