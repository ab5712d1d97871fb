"""Simulator frames through the recording writer and reader: bit-exact colour, depth to the quantisation,
ground truth, parts and events; ``open_source("sim:...")`` and ``record --source sim:...``."""

from __future__ import annotations

import filecmp

import numpy as np
import pytest

from app.cli import main
from tracker.sources.recording import RecordingSource, RecordingWriter
from tracker.sources.registry import open_source
from tracker.sources.simulator import SimOptions, SimulatedTable

SMALL_SIM = SimOptions(width=160, height=120, focal=131.25)


def test_simulator_round_trip(tmp_path):
    sim = SimulatedTable("guess-2", seed=7, options=SMALL_SIM, n_frames=3)
    frames = list(sim)
    with RecordingWriter(tmp_path / "a", sim.intrinsics, 0.001, sim.parts, sim.initial_poses) as w:
        for f in frames:
            w.write(f, groundtruth=f.meta["groundtruth"])
        for ev in sim.events:
            w.write_event(ev.t, ev.type, ev.parts)
    rec = RecordingSource(tmp_path / "a")
    assert len(rec) == 3 and rec.intrinsics == sim.intrinsics
    assert [p.name for p in rec.parts] == [p.name for p in sim.parts]
    assert all(r.box == s.box and r.color == s.color for r, s in zip(rec.parts, sim.parts, strict=True))
    for name, pose in sim.initial_poses.items():
        np.testing.assert_allclose(rec.initial_poses[name].as_matrix(), pose.as_matrix(), atol=1e-12)
    assert [(e.t, e.type, tuple(e.parts)) for e in rec.events] == [(e.t, e.type, tuple(e.parts)) for e in sim.events]
    for f, g in zip(frames, rec, strict=True):
        assert g.timestamp == f.timestamp
        np.testing.assert_array_equal(g.color, f.color)
        np.testing.assert_array_equal(np.isnan(g.depth), np.isnan(f.depth) | (f.depth < 0.0005))
        ok = np.isfinite(g.depth)
        assert np.max(np.abs(g.depth[ok] - f.depth[ok])) <= 0.0005 + 1e-6
        gt = rec.groundtruth(g.index)
        for name, pose in f.meta["groundtruth"]["poses"].items():
            np.testing.assert_allclose(gt[name].as_matrix(), pose.as_matrix(), atol=1e-12)
        assert g.meta["groundtruth"]["hand_box"] == (None if f.meta["groundtruth"]["hand_box"] is None
                                                     else list(f.meta["groundtruth"]["hand_box"]))
    # reading and writing again reproduces every file
    with RecordingWriter(tmp_path / "b", rec.intrinsics, rec.depth_scale, rec.parts, rec.initial_poses) as w:
        for g in rec:
            w.write(g, groundtruth=g.meta["groundtruth"])
        for ev in rec.events:
            w.write_event(ev.t, ev.type, ev.parts)
    for name in ("camera.json", "frames.jsonl", "objects.json", "groundtruth.jsonl", "events.jsonl",
                 "color/000002.png", "depth/000002.png"):
        assert filecmp.cmp(tmp_path / "a" / name, tmp_path / "b" / name, shallow=False), name


def test_open_sim_source_and_errors():
    src = open_source("sim:static", seed=3, n_frames=2)
    assert isinstance(src, SimulatedTable) and len(src) == 2
    with pytest.raises(ValueError, match=r"unknown scenario 'nope' in sim:nope; scenarios: static, "):
        open_source("sim:nope")


def test_record_command_from_simulator(tmp_path, capsys):
    out = tmp_path / "rec"
    assert main(["record", "--source", "sim:static", "--seed", "2", "--out", str(out), "--frames", "2"]) == 0
    assert "wrote 2 frames" in capsys.readouterr().out
    rec = RecordingSource(out)
    sim = SimulatedTable("static", seed=2, n_frames=2)
    assert len(rec) == 2 and rec.has_groundtruth
    assert set(rec.initial_poses) == {p.name for p in sim.parts}
    np.testing.assert_array_equal(rec.read(1).color, list(sim)[1].color)
