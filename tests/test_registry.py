"""Source names: parsing, errors, and opening recordings and cameras through open_source; the record command."""

from __future__ import annotations

import json

import numpy as np
import pytest
from shared_data import REAL, needs_shared

from app.cli import main
from tracker.frame import Frame
from tracker.geometry.camera import Intrinsics
from tracker.geometry.pose import Pose
from tracker.sources import camera as camera_mod
from tracker.sources.base import SourceError
from tracker.sources.recording import RecordingSource, RecordingWriter
from tracker.sources.registry import open_source, parse_source_spec

VISP = REAL / "visp-cube-desk"

SMALL = Intrinsics(40, 30, 40.0, 40.0, 19.5, 14.5)


def test_parse_forms(tmp_path):
    assert parse_source_spec("sim:guess-2") == ("sim", "guess-2")
    assert parse_source_spec("recording:/some/dir") == ("recording", "/some/dir")
    assert parse_source_spec("camera:4,2") == ("camera", "4,2")
    assert parse_source_spec(str(tmp_path)) == ("recording", str(tmp_path))


@pytest.mark.parametrize("spec", ["video:0", "webcam", "sim:", "", "/no/such/recording"])
def test_bad_specs_list_valid_forms(spec):
    with pytest.raises(ValueError) as exc:
        parse_source_spec(spec)
    msg = str(exc.value)
    assert "sim:<scenario>" in msg and "recording:<dir>" in msg and "camera:<colour>[,<depth>]" in msg


def test_unknown_scheme_is_named():
    with pytest.raises(ValueError, match=r"unknown source scheme 'video:'"):
        open_source("video:0")


def test_unknown_option():
    with pytest.raises(ValueError, match=r"unknown source option\(s\) sede"):
        open_source(f"recording:{VISP}", sede=3)


@needs_shared
def test_open_recording_both_ways():
    for spec in (f"recording:{VISP}", str(VISP)):
        with open_source(spec, seed=5, calibration=None) as src:  # options for other sources are ignored
            assert isinstance(src, RecordingSource) and len(src) == 10
    src = open_source(str(VISP), loop=True)
    assert src.loop is True


def test_open_missing_recording():
    with pytest.raises(SourceError, match="recording directory not found"):
        open_source("recording:/no/such/recording")


def test_open_camera_without_devices(tmp_path, monkeypatch):
    monkeypatch.setattr(camera_mod, "list_video_devices", lambda: [])
    monkeypatch.setattr(camera_mod, "depth_backends", lambda: {"OpenNI2": False, "Orbbec": False})
    with pytest.raises(SourceError, match=r"camera:0: no depth stream .* sim:guess-2"):
        open_source("camera:0")
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps({"color": SMALL.to_dict(), "depth": SMALL.to_dict()}))
    with pytest.raises(SourceError, match=r"camera:9997,9998: cannot open the camera"):
        open_source("camera:9997,9998", calibration=str(cal))


# --- the record command ------------------------------------------------------------------------------------


def _recording_with_groundtruth(root):
    rng = np.random.default_rng(0)
    with RecordingWriter(root, SMALL, parts=None) as w:
        for i in range(6):
            color = rng.integers(0, 256, size=(30, 40, 3), dtype=np.uint8)
            depth = rng.uniform(0.5, 1.0, size=(30, 40)).astype(np.float32)
            w.write(Frame(i, i * 0.1, color, depth, SMALL), groundtruth={"red": Pose([0.0, 0.0, 0.5 + i * 0.01])})
        w.write_event(0.15, "connected", ["red", "green"])
        w.write_event(0.45, "disconnected", ["red", "green"])


def test_record_command_copies_frames_groundtruth_and_events(tmp_path, capsys):
    _recording_with_groundtruth(tmp_path / "in")
    out = tmp_path / "out"
    assert main(["record", "--source", f"recording:{tmp_path / 'in'}", "--out", str(out), "--frames", "4"]) == 0
    assert "wrote 4 frames" in capsys.readouterr().out
    src = RecordingSource(out)
    assert len(src) == 4
    assert src.groundtruth(3)["red"].t[2] == pytest.approx(0.53)
    assert [e.t for e in src.events] == [0.15]  # events after the last recorded frame are left out
    orig = RecordingSource(tmp_path / "in")
    np.testing.assert_array_equal(src.read(2).color, orig.read(2).color)
    np.testing.assert_array_equal(src.read(2).depth, orig.read(2).depth)


def test_record_command_seconds_and_errors(tmp_path, capsys):
    _recording_with_groundtruth(tmp_path / "in")
    out = tmp_path / "out"
    assert main(["record", "--source", str(tmp_path / "in"), "--out", str(out), "--seconds", "0.25"]) == 0
    assert len(RecordingSource(out)) == 3  # t = 0.0, 0.1, 0.2
    # an existing recording is not overwritten without --overwrite
    assert main(["record", "--source", str(tmp_path / "in"), "--out", str(out)]) == 1
    assert "already holds a recording" in capsys.readouterr().err
    assert main(["record", "--source", "bogus:1", "--out", str(tmp_path / "x")]) == 1
    assert "valid forms" in capsys.readouterr().err
