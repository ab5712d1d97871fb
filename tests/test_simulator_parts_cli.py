"""Simulator: other rigid parts (a box rod and a trimesh mesh), the triangle rasterizer, options and the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from app.cli import main as cli_main
from tracker.geometry.parts import ROD_SIZE, PartSpec
from tracker.geometry.pose import Pose
from tracker.sources.simulator import SimOptions, SimulatedTable
from tracker.sources.simulator import rasterizer as rz
from tracker.sources.simulator.scene import AMBIENT, DIFFUSE


def _buffers(h=120, w=160):
    return (
        np.full((h, w), np.inf, np.float32),
        np.ones((h, w), np.float32),
        np.zeros((h, w, 3), np.float32),
        np.full((h, w), -1, np.int16),
        np.zeros(2, np.int64),
    )


def test_triangle_rasterizer_matches_box_ray_casting():
    pose = Pose.from_rotvec(np.array([0.4, -0.7, 0.2]), np.array([0.01, -0.005, 0.5]))
    size = np.array(ROD_SIZE)
    fx = fy = 200.0
    cx, cy = 79.5, 59.5
    light = np.array([0.0, -1.0, 0.0])
    albedo = np.array([200.0, 100.0, 50.0])
    d1, c1, col1, ids1, hits1 = _buffers()
    rz.render_box(d1, c1, col1, ids1, hits1, fx, fy, cx, cy, pose.R, pose.t, size / 2, albedo, light, AMBIENT, DIFFUSE,
                  0, 0, 0, 160, 120, 0.0, 0.0)  # fmt: skip
    mesh = trimesh.creation.box(extents=size)
    verts = pose.transform_points(mesh.vertices)
    tris = np.ascontiguousarray(verts[mesh.faces])
    normals = np.ascontiguousarray(mesh.face_normals @ pose.R.T)
    d2, c2, col2, ids2, hits2 = _buffers()
    local = np.empty((120, 160), np.float32)
    rz.render_triangles(d2, c2, col2, ids2, hits2, local, fx, fy, cx, cy, tris, normals, albedo, light, AMBIENT,
                        DIFFUSE, 0, 0, 0, 160, 120)  # fmt: skip
    both = np.isfinite(d1) & np.isfinite(d2)
    assert both.sum() > 300
    assert np.abs(d1[both] - d2[both]).max() < 1e-4
    # coverage agrees up to the pixels on the silhouette
    assert abs(int(np.isfinite(d1).sum()) - int(np.isfinite(d2).sum())) < 0.05 * both.sum()
    assert hits1[0] == np.isfinite(d1).sum() and hits2[0] == np.isfinite(d2).sum()
    assert np.allclose(c1[both], c2[both], atol=1e-3)


def test_extra_rod_and_mesh_parts_are_rendered_at_their_groundtruth(tmp_path):
    path = tmp_path / "wedge.obj"
    mesh = trimesh.creation.cylinder(radius=0.02, height=0.05, sections=16)
    mesh.export(path)
    rod = PartSpec("rod", box=ROD_SIZE, color=(200, 200, 210))
    wedge = PartSpec("wedge", box=None, mesh=str(path), color=(90, 200, 90))
    src = SimulatedTable("static", seed=4, n_frames=2, options=SimOptions(extra_parts=(rod, wedge)))
    assert [p.name for p in src.parts][-2:] == ["rod", "wedge"]
    clean = src.render_clean(0)
    frame = src.render(0)
    gt = frame.meta["groundtruth"]
    n, d = src.table_plane
    for name, part in (("rod", rod), ("wedge", wedge)):
        pid = [p.name for p in src.parts].index(name)
        pose = gt["poses"][name]
        assert gt["visible"][name] == pytest.approx(1.0)
        assert (clean["ids"] == pid).sum() > 150
        uv = src.intrinsics.project(pose.t[None])[0]
        assert clean["ids"][int(round(uv[1])), int(round(uv[0]))] == pid
        # resting on the table: the lowest point is on the plane
        heights = pose.transform_points(part.vertices()) @ n + d
        assert heights.min() == pytest.approx(0.0, abs=1e-6)
    # a lying rod: its long axis is horizontal
    rod_axis = gt["poses"]["rod"].R[:, 2]
    assert abs(rod_axis @ n) < 1e-6


def test_options_are_validated_and_change_the_script():
    with pytest.raises(ValueError, match="occlusion"):
        SimOptions(occlusion=3.0)
    with pytest.raises(ValueError, match="unknown simulator scenario"):
        SimulatedTable("nope")
    slow = SimulatedTable("guess-1", seed=3)
    fast = SimulatedTable("guess-1", seed=3, options=SimOptions(speed=2.0))
    assert fast.duration < 0.7 * slow.duration
    fixed = SimulatedTable("static", seed=3, options=SimOptions(camera_distance=0.75, camera_elevation_deg=50.0))
    assert fixed.camera.distance == 0.75 and fixed.camera.elevation_deg == 50.0
    assert SimulatedTable("static", seed=3, n_frames=7).n_frames == 7
    assert len(list(SimulatedTable("static", seed=3, n_frames=3))) == 3


def test_wider_hand_occludes_more():
    def hand_pixels(occ: float) -> int:
        src = SimulatedTable("guess-2", seed=5, options=SimOptions(occlusion=occ))
        hp = src.timeline.passes[0]
        total = 0
        for k in range(int(hp.t_grasp * 30), int(hp.t_release * 30), 10):
            total += int((src.render_clean(k)["ids"] == len(src.parts)).sum())
        return total

    assert hand_pixels(2.0) > 1.2 * hand_pixels(0.0)
    # without the hand nothing is drawn but the parts still move
    src = SimulatedTable("guess-2", seed=5, options=SimOptions(show_hand=False))
    hp = src.timeline.passes[0]
    k = int((hp.t_grasp + hp.t_release) * 15)
    clean = src.render_clean(k)
    assert clean["hand_box"] is None and not (clean["ids"] == len(src.parts)).any()
    assert not np.allclose(src.groundtruth(k)[hp.part].t, src.groundtruth(0)[hp.part].t)


def test_cli_lists_scenarios_and_writes_a_recording(tmp_path, capsys):
    assert cli_main(["simulate", "--list"]) == 0
    out = capsys.readouterr().out
    for name in ("static", "free", "guidance-demo", "guess-1", "guess-2", "guess-3", "learning-4", "learning-5"):
        assert name in out
    rec = tmp_path / "rec"
    assert cli_main(["simulate", "guess-2", "--out", str(rec), "--seed", "7", "--frames", "4"]) == 0
    out = capsys.readouterr().out
    assert "4 frames" in out and "parts (5)" in out
    from tracker.sources.recording import RecordingSource

    src = RecordingSource(rec)
    assert len(src) == 4
    sim = SimulatedTable("guess-2", seed=7, n_frames=4)
    f_rec = src.read(3)
    f_sim = sim.render(3)
    assert np.array_equal(f_rec.color, f_sim.color)
    ok = np.isfinite(f_sim.depth)
    assert np.array_equal(np.isfinite(f_rec.depth), ok)
    assert np.abs(f_rec.depth[ok] - f_sim.depth[ok]).max() < 1e-6
    gt = src.groundtruth(3)
    assert np.allclose(gt["red"].t, f_sim.meta["groundtruth"]["poses"]["red"].t)
    objects = json.loads((rec / "objects.json").read_text())["objects"]
    assert [o["name"] for o in objects] == ["red", "green", "blue", "yellow", "orange"]
    # errors: unknown scenario / missing --out
    assert cli_main(["simulate", "nope", "--out", str(tmp_path / "x")]) == 1
    assert cli_main(["simulate", "static"]) == 1
