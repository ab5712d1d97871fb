"""Tests of the simulated RGB-D table: determinism, ground truth vs rendering, sensor noise, events, hand."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.geometry.parts import CUBE_EDGE, PRESET_COLORS
from tracker.geometry.pose import Pose
from tracker.geometry.symmetry import cube_group
from tracker.sources.simulator import (
    DepthSensorModel,
    SimOptions,
    SimulatedTable,
    face_adjacent,
    list_scenarios,
)
from tracker.sources.simulator.scenarios import cube_yaw, rot_y

A = CUBE_EDGE
NAMES = ["static", "free", "guidance-demo", "guess-1", "guess-2", "guess-3", "learning-4", "learning-5",
         "hands-s1", "hands-s2", "hands-s3"]


@pytest.fixture(scope="module")
def static_src() -> SimulatedTable:
    return SimulatedTable("static", seed=3, n_frames=5)


@pytest.fixture(scope="module")
def guess1() -> SimulatedTable:
    return SimulatedTable("guess-1", seed=11)


def test_scenario_list_has_every_required_scenario():
    listed = list_scenarios()
    assert [s.name for s in listed] == NAMES
    assert all(s.description and "\n" not in s.description for s in listed)


def test_same_seed_gives_identical_frames_and_different_seed_differs():
    a = SimulatedTable("guess-2", seed=7, n_frames=400)
    b = SimulatedTable("guess-2", seed=7, n_frames=400)
    c = SimulatedTable("guess-2", seed=8, n_frames=400)
    # frame k is the same whether frames before it were rendered or skipped
    b.render(10)
    for k in (0, 150, 300):
        fa, fb = a.render(k), b.render(k)
        assert np.array_equal(fa.color, fb.color)
        assert np.array_equal(fa.depth, fb.depth, equal_nan=True)
        assert fa.timestamp == pytest.approx(k / 30.0)
    assert [e.to_dict() for e in a.events] == [e.to_dict() for e in b.events]
    fc = c.render(150)
    assert not np.array_equal(a.render(150).color, fc.color)
    # iteration yields the same frames as random access
    it = iter(SimulatedTable("guess-2", seed=7, n_frames=3))
    f0 = next(it)
    assert np.array_equal(f0.color, a.render(0).color)


def _project(src: SimulatedTable, p: np.ndarray) -> tuple[int, int]:
    uv = src.intrinsics.project(p[None])[0]
    return int(round(uv[0])), int(round(uv[1]))


def _ray_box_depth(src: SimulatedTable, pose: Pose, size: float, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Independent slab-method depth of a cube at pixels (u, v); NaN where the ray misses."""
    intr = src.intrinsics
    d = np.stack([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, np.ones_like(u, float)], axis=-1)
    R = pose.R
    o = -R.T @ pose.t
    dl = d @ R  # Rᵀ d for each ray
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-size / 2 - o) / dl
        t2 = (size / 2 - o) / dl
    tn = np.minimum(t1, t2).max(axis=-1)
    tf = np.maximum(t1, t2).min(axis=-1)
    return np.where(tn <= tf, tn, np.nan)


def _chroma(rgb) -> np.ndarray:
    c = np.asarray(rgb, float)
    return c / c.sum(axis=-1, keepdims=True)


def test_groundtruth_agrees_with_rendering(static_src):
    src = static_src
    frame = src.render(2)
    clean = src.render_clean(2)
    gt = frame.meta["groundtruth"]
    assert gt["hand_box"] is None
    assert set(gt["poses"]) == {p.name for p in src.parts}
    names = [p.name for p in src.parts]
    model = src.options.depth_model
    for pid, part in enumerate(src.parts):
        pose = gt["poses"][part.name]
        assert gt["visible"][part.name] == pytest.approx(1.0)
        # the projected centre lands on the part's own pixels, of the right colour
        u, v = _project(src, pose.t)
        assert clean["ids"][v, u] == pid
        patch = frame.color[v - 2 : v + 3, u - 2 : u + 3].reshape(-1, 3).mean(axis=0)
        dists = {n: np.linalg.norm(_chroma(patch) - _chroma(PRESET_COLORS[n])) for n in names}
        assert min(dists, key=dists.get) == part.name
        # noise-free depth at the part's pixels is the ray/cube intersection of the GT pose
        vv, uu = np.nonzero(clean["ids"] == pid)
        assert len(vv) > 100
        expect = _ray_box_depth(src, pose, A, uu.astype(float), vv.astype(float))
        assert np.nanmax(np.abs(clean["depth"][vv, uu] - expect)) < 1e-5
        # the noisy depth (shifted by the misregistration) matches within the noise model
        us = uu - model.shift_u
        vs = vv - model.shift_v
        ok = (us >= 0) & (us < src.intrinsics.width) & (vs >= 0) & (vs < src.intrinsics.height)
        noisy = frame.depth[vs[ok], us[ok]]
        ref = expect[ok]
        valid = np.isfinite(noisy)
        assert valid.mean() > 0.7
        err = np.abs(noisy[valid] - ref[valid])
        sigma = model.sigma(ref[valid])
        assert np.median(err / sigma) < 1.5
        assert np.mean(err < 4 * sigma + model.quant_step) > 0.95


def test_depth_noise_statistics_match_the_model():
    model = DepthSensorModel(dropout=0.04, edge_missing=0.0, edge_flying=0.0, grazing_start_deg=89.0,
                             grazing_end_deg=89.9)  # fmt: skip
    src = SimulatedTable("static", seed=5, n_frames=3, options=SimOptions(depth_model=model, camera_distance=0.8))
    clean = src.render_clean(1)
    ids = clean["ids"].copy()
    z = clean["depth"].copy()
    frame = src.render(1)
    h, w = z.shape
    # a flat table patch with no part: rows/cols where the table is and ids are background
    v0, v1, u0, u1 = h // 2 - 60, h // 2 + 60, 20, w - 20
    region_ids = ids[v0:v1, u0:u1]
    su, sv = model.shift_u, model.shift_v
    noisy = frame.depth[v0 - sv : v1 - sv, u0 - su : u1 - su]
    ref = z[v0:v1, u0:u1]
    bg = region_ids == -1
    # keep away from parts (their edges): erode the background mask
    import cv2

    bg = cv2.erode(bg.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    assert bg.sum() > 20000
    valid = np.isfinite(noisy) & bg
    frac_missing = 1.0 - valid.sum() / bg.sum()
    assert frac_missing == pytest.approx(0.04, abs=0.006)
    res = (noisy - ref)[valid]
    zz = ref[valid]
    expected = np.sqrt(model.sigma(zz) ** 2 + model.quant_step**2 / 12.0)
    ratio = res.std() / np.sqrt(np.mean(expected**2))
    assert 0.85 < ratio < 1.15
    assert abs(res.mean()) < 0.3e-3
    # quantisation: every value is a whole number of millimetres
    q = noisy[np.isfinite(noisy)] / model.quant_step
    assert np.allclose(q, np.round(q), atol=1e-3)


def test_noise_grows_quadratically_with_depth():
    model = DepthSensorModel(quantization="none", dropout=0.0, edge_missing=0.0, edge_flying=0.0)
    clean = np.concatenate([np.full((100, 200), 0.5, np.float32), np.full((100, 200), 1.0, np.float32)])
    cos = np.ones_like(clean)
    out = model.apply(clean, cos, key=1234)
    s_near = np.nanstd(out[5:95, 5:195] - 0.5)
    s_far = np.nanstd(out[105:195, 5:195] - 1.0)
    assert s_near == pytest.approx(1.4e-3 * 0.25, rel=0.1)
    assert s_far == pytest.approx(1.4e-3 * 1.0, rel=0.1)
    # edges of the jump produce missing or flying pixels; the rest are not missing
    edge = DepthSensorModel(dropout=0.0, edge_missing=0.5, edge_flying=0.5, shift_u=0)
    out = edge.apply(clean, cos, key=99)
    rows = out[99:101, 5:195]
    between = (rows > 0.52) & (rows < 0.98)
    assert np.isnan(rows).mean() > 0.3
    assert between.any()
    assert np.isfinite(out[10:90, 5:195]).all()


def test_events_are_consistent_with_groundtruth(guess1):
    src = guess1
    structure = src.scenario.structure
    events = src.events
    assert [e.type for e in events] == ["connected"] * 4
    assert sorted(tuple(e.parts) for e in events) == sorted(structure.connections)
    for e in events:
        k = int(np.ceil(e.t * 30.0)) + 1
        poses = src.groundtruth(k)
        assert face_adjacent(poses[e.parts[0]], poses[e.parts[1]])
        before = src.groundtruth(max(0, int(e.t * 30.0) - 20))
        assert not face_adjacent(before[e.parts[0]], before[e.parts[1]])


def test_free_scenario_disconnections_separate_parts():
    found = False
    for seed in range(6):
        src = SimulatedTable("free", seed=seed, options=SimOptions(free_moves=8))
        for e in src.events:
            k = int(np.ceil(e.t * 30.0)) + 20
            if k >= src.n_frames:
                continue
            poses = src.groundtruth(k)
            adjacent = face_adjacent(poses[e.parts[0]], poses[e.parts[1]])
            assert adjacent == (e.type == "connected")
            found |= e.type == "disconnected"
        if found:
            break
    assert found, "no free-scenario seed produced a disconnection"


def test_hand_occludes_while_carrying(guess1):
    src = guess1
    hp = src.timeline.passes[1]
    mid = int((hp.t_grasp + hp.t_release) / 2 * 30)
    boxes = []
    min_vis = 1.0
    for k in range(int(hp.t_start * 30) + 1, int(hp.t_end * 30), 6):
        gt = src.render_clean(k)
        boxes.append(gt["hand_box"])
        min_vis = min(min_vis, min(gt["visible"].values()))
    assert all(b is not None for b in boxes[1:-1])
    assert min_vis < 0.5
    f = src.render(mid)
    u0, v0, u1, v1 = f.meta["groundtruth"]["hand_box"]
    assert 0 <= u0 < u1 <= 640 and 0 <= v0 < v1 <= 480
    # skin colour and near depth inside the hand box
    ids = src.render_clean(mid)["ids"]
    hand = ids == len(src.parts)
    assert hand.sum() > 2000
    assert v1 == 480 or v1 > 400  # the arm enters from the bottom edge


def test_excursions_take_the_part_out_of_view():
    src = SimulatedTable("guess-2", seed=4, options=SimOptions(excursions=True))
    out_of_view = 0
    for hp in src.timeline.passes:
        for k in range(int(hp.t_grasp * 30) + 1, int(hp.t_release * 30), 3):
            pose = src.groundtruth(k)[hp.part]
            u, v = src.intrinsics.project(pose.t[None])[0]
            if u < -60 or u > 700:
                vis = src.render_clean(k)["visible"][hp.part]
                assert vis == 0.0
                out_of_view += 1
    assert out_of_view > 0


@pytest.mark.parametrize("name", ["guidance-demo", "guess-1", "guess-2", "guess-3", "learning-4", "learning-5"])
def test_every_scenario_builds_its_structure(name):
    src = SimulatedTable(name, seed=21)
    s = src.scenario.structure
    T = src.table_to_camera.inverse()
    final = {n: T @ p for n, p in src.groundtruth(src.n_frames - 1).items()}
    first = s.cells[0][0]
    yaw = cube_yaw(final[first].R)
    assert abs(yaw) <= np.radians(20.0) + 1e-9
    Rs = rot_y(yaw)
    group = cube_group()
    for n, cell in s.cells:
        rel = Rs.T @ (final[n].t - final[first].t) / A
        assert np.allclose(rel, np.subtract(cell, s.cell(first)), atol=0.03), (n, rel)
        local = Rs.T @ final[n].R
        assert np.min(np.abs(group - local[None]).max(axis=(1, 2))) < 1e-6
        assert abs(final[n].t[1] - (cell[1] + 0.5) * A) < 1e-6  # resting on the table / on the cube below
    assert len(src.events) == len(s.connections)
    assert {tuple(e.parts) for e in src.events} == set(s.connections)
    if name.startswith("learning"):  # the row reads left→right in the image
        cam = src.groundtruth(src.n_frames - 1)
        us = [src.intrinsics.project(cam[n].t[None])[0, 0] for n, _ in s.cells]
        assert us == sorted(us)
    # distractors never move
    start = src.groundtruth(0)
    for n in src.scenario.distractors:
        assert np.allclose(start[n].t, src.groundtruth(src.n_frames - 1)[n].t)


def test_cubes_start_scattered_in_view_with_random_symmetric_orientations():
    seen = set()
    for name in ("guess-3", "learning-5"):
        src = SimulatedTable(name, seed=2)
        T = src.table_to_camera.inverse()
        poses = src.initial_poses
        pts = []
        for p in poses.values():
            uv = src.intrinsics.project(p.t[None])[0]
            assert 0 < uv[0] < 640 and 0 < uv[1] < 480
            pt = T @ p
            assert np.hypot(pt.t[0], pt.t[2]) <= 0.25 + 1e-9
            assert pt.t[1] == pytest.approx(A / 2)
            pts.append(pt.t)
            local = rot_y(cube_yaw(pt.R)).T @ pt.R
            seen.add(tuple(np.round(local, 3).ravel()))
        pts = np.array(pts)
        d = np.linalg.norm(pts[:, None] - pts[None], axis=-1) + np.eye(len(pts))
        assert d.min() > 1.5 * A
    assert len(seen) > 3


def test_table_plane_matches_depth(static_src):
    n, d = static_src.table_plane
    assert np.linalg.norm(n) == pytest.approx(1.0)
    clean = static_src.render_clean(0)
    v, u = 240, 320
    p = static_src.intrinsics.backproject(u, v, clean["depth"][v, u])
    if clean["ids"][v, u] == -1:
        assert abs(n @ p + d) < 1e-6
    # the camera is 0.6–0.9 m from the table centre, looking down at 40–60°
    assert 0.6 <= static_src.camera.distance <= 0.9
    assert 40 <= static_src.camera.elevation_deg <= 60
    assert n[1] < 0  # up on the table is up (−y) in the image


def test_disparity_noise_and_quantisation():
    model = DepthSensorModel(noise_on="disparity", quantization="disparity", dropout=0.0, edge_missing=0.0,
                             edge_flying=0.0, shift_u=0)  # fmt: skip
    clean = np.full((150, 150), 0.8, np.float32)
    out = model.apply(clean, np.ones_like(clean), key=7)
    assert np.isfinite(out).all()
    disp = model.focal_baseline / out.astype(np.float64)
    steps = disp / model.disparity_step
    assert np.allclose(steps, np.round(steps), atol=1e-3)  # values lie on the disparity grid
    # the step at 0.8 m is ~2 mm, so the spread is set by noise and quantisation together
    step_z = 0.8**2 / model.focal_baseline * model.disparity_step
    expected = np.sqrt(model.sigma(0.8) ** 2 + step_z**2 / 12)
    assert out.std() == pytest.approx(expected, rel=0.2)
    assert abs(out.mean() - 0.8) < 2e-4


def test_colour_noise_matches_the_model():
    from tracker.sources.simulator import ColorSensorModel

    cm = ColorSensorModel(noise_sigma=3.0, gain_amplitude=0.0, ramp_amplitude=0.0, vignetting=0.0, blur_sigma=0.0)
    src = SimulatedTable("static", seed=9, n_frames=2, options=SimOptions(color_model=cm))
    clean = src.render_clean(1)["color"].copy()
    frame = src.render(1)
    res = frame.color[100:380, 50:590].astype(float) - clean[100:380, 50:590]
    ok = (clean[100:380, 50:590] > 10).all(axis=-1) & (clean[100:380, 50:590] < 245).all(axis=-1)
    r = res[ok]
    assert abs(r.mean()) < 0.1
    assert r.std() == pytest.approx(np.sqrt(3.0**2 + 1 / 12), rel=0.08)


def test_projector_shadow_band_left_of_a_near_surface():
    model = DepthSensorModel(dropout=0.0, edge_missing=0.0, edge_flying=0.0, shift_u=0, noise_coeff=0.0)
    clean = np.full((40, 200), 1.0, np.float32)
    clean[:, 100:140] = 0.8  # a nearer block
    out = model.apply(clean, np.ones_like(clean), key=3, fx=525.0)
    width = 525.0 * 0.075 * (1 / 0.8 - 1 / 1.0)  # ≈ 9.8 px of background the projector cannot reach
    row = out[20]
    assert np.isnan(row[101 - int(width) : 100]).all()
    assert np.isfinite(row[: 100 - int(np.ceil(width)) - 1]).all()
    assert np.isfinite(row[100:]).all()  # block and the background to its right are measured
    none = DepthSensorModel(projector_baseline=0.0, dropout=0.0, edge_missing=0.0, edge_flying=0.0, shift_u=0)
    assert np.isfinite(none.apply(clean, np.ones_like(clean), key=3)).all()


@pytest.mark.parametrize("name, seed, start", [("guidance-demo", 0, 100), ("hands-s3", 101, 40)])
def test_frames_in_sequence_equal_frames_rendered_afresh(name, seed, start):
    """Rendering puts the background back only where the previous frame drew (its geometry, shadows, motion blur):
    consecutive frames with a moving hand and its shadow equal the same frames rendered by a fresh table."""
    seq = SimulatedTable(name, seed=seed)
    seq.render(start - 1)
    moved = 0
    for k in range(start, start + 4):
        a, b = seq.render(k), SimulatedTable(name, seed=seed).render(k)
        assert np.array_equal(a.color, b.color)
        assert np.array_equal(a.depth, b.depth, equal_nan=True)
        assert a.meta["groundtruth"]["visible"] == b.meta["groundtruth"]["visible"]
        assert a.meta["groundtruth"]["hand_box"] == b.meta["groundtruth"]["hand_box"]
        moved += a.meta["groundtruth"]["hand_box"] is not None or bool(a.meta["groundtruth"].get("hand_boxes"))
    assert moved == 4  # a hand was drawn on every frame


def test_render_into_given_buffers_gives_the_same_frame():
    src = SimulatedTable("guidance-demo", seed=0, n_frames=200)
    color, depth = np.zeros((480, 640, 3), np.uint8), np.zeros((480, 640), np.float32)
    f = src.render(150, out=(color, depth))
    assert f.color is color and f.depth is depth
    g = SimulatedTable("guidance-demo", seed=0, n_frames=200).render(150)
    assert np.array_equal(color, g.color) and np.array_equal(depth, g.depth, equal_nan=True)
