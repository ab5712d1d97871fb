"""``assembly-agent track`` on a short simulated recording, and its error messages."""

from __future__ import annotations

import json

import pytest

from app.cli import main
from tracker.sources.recording import RecordingWriter
from tracker.sources.simulator import SimulatedTable


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    root = tmp_path_factory.mktemp("rec") / "static"
    src = SimulatedTable("static", seed=1, realtime=False, n_frames=8)
    w = RecordingWriter(root, src.intrinsics, parts=src.parts, initial_poses=src.initial_poses)
    for f in src:
        w.write(f, groundtruth=f.meta["groundtruth"]["poses"])
    w.close()
    return root


def test_track_writes_poses_and_reports_errors(recording, tmp_path, capsys):
    out = tmp_path / "poses.jsonl"
    rc = main(["track", str(recording), "--out", str(out), "--particles", "60"])
    assert rc == 0
    lines = [json.loads(s) for s in out.read_text().splitlines()]
    assert [d["index"] for d in lines] == list(range(8))
    assert set(lines[0]["poses"]) == {"red", "green", "blue", "yellow", "orange"}
    assert len(lines[0]["poses"]["red"]["t"]) == 3 and len(lines[0]["poses"]["red"]["q"]) == 4
    text = capsys.readouterr().out
    assert "fps" in text and "t mean" in text and "all" in text
    assert "table plane: found" in text  # the table supports the parts (not a face of one of them)
    # the static scene is tracked to a few millimetres
    row = [s for s in text.splitlines() if s.startswith("all")][0]
    t_median = float(row.split("|")[1].split()[1])
    assert t_median < 6.0


def test_track_errors(recording, tmp_path, capsys):
    assert main(["track", str(tmp_path / "nowhere")]) == 1
    assert "nowhere" in capsys.readouterr().err
    bad = tmp_path / "objects.json"
    bad.write_text(json.dumps({"objects": [{"name": "m", "shape": {"mesh": "missing.obj"}, "color": None,
                                            "pose": {"t": [0, 0, 0.6], "q": [0, 0, 0, 1]}}]}))
    assert main(["track", str(recording), "--objects", str(bad), "--frames", "2"]) == 1
    assert "missing.obj" in capsys.readouterr().err
    nopose = tmp_path / "nopose.json"
    nopose.write_text(json.dumps({"objects": [{"name": "a", "shape": {"box": [0.036, 0.036, 0.036]}}]}))
    assert main(["track", str(recording), "--objects", str(nopose), "--init", "given"]) == 1
    assert "no first-frame pose" in capsys.readouterr().err
    assert main(["track", str(recording), "--preset", "bogus"]) == 1
    assert "unknown tracker preset" in capsys.readouterr().err


def test_track_and_serve_default_to_the_fused_odometry(recording, tmp_path, capsys):
    """``track`` and ``serve`` run the odometry of :data:`tracker.odometry.ego_motion.DEFAULT_MODE` unless told
    otherwise; on a fixed camera it idles and every line of ``--out`` carries the camera pose at the origin."""
    from app.commands.track import DEFAULT_ODOMETRY
    from app.settings import Settings
    from tracker.odometry.ego_motion import DEFAULT_MODE

    assert DEFAULT_ODOMETRY == DEFAULT_MODE == Settings().odometry == "fused"
    out = tmp_path / "poses.jsonl"
    assert main(["track", str(recording), "--out", str(out), "--particles", "60", "--frames", "4"]) == 0
    assert "odometry fused: 4 of 4 camera poses measured" in capsys.readouterr().err
    lines = [json.loads(s) for s in out.read_text().splitlines()]
    assert len(lines) == 4
    for d in lines:  # the simulated camera of this recording does not move
        assert max(abs(x) for x in d["camera"]["t"]) < 1e-3
    off = tmp_path / "off.jsonl"
    assert main(["track", str(recording), "--out", str(off), "--particles", "60", "--frames", "4",
                 "--odometry", "off"]) == 0
    assert "odometry" not in capsys.readouterr().err
    assert all("camera" not in json.loads(s) for s in off.read_text().splitlines())
