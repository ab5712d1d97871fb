"""Broken recordings give SourceErrors that name the file and the frame or line."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from tracker.frame import Frame
from tracker.geometry.camera import Intrinsics
from tracker.sources.base import SourceError
from tracker.sources.recording import RecordingSource, RecordingWriter

SMALL = Intrinsics(40, 30, 40.0, 40.0, 19.5, 14.5)


@pytest.fixture
def rec(tmp_path) -> Path:
    rng = np.random.default_rng(0)
    root = tmp_path / "rec"
    with RecordingWriter(root, SMALL) as w:
        for i in range(3):
            color = rng.integers(0, 256, size=(30, 40, 3), dtype=np.uint8)
            depth = rng.uniform(0.5, 1.0, size=(30, 40)).astype(np.float32)
            w.write(Frame(i, i * 0.1, color, depth, SMALL))
    return root


def _edit_camera(root: Path, **changes) -> None:
    cam = json.loads((root / "camera.json").read_text())
    for k, v in changes.items():
        if v is None:
            cam.pop(k)
        else:
            cam[k] = v
    (root / "camera.json").write_text(json.dumps(cam))


def test_missing_directory(tmp_path):
    with pytest.raises(SourceError, match="recording directory not found"):
        RecordingSource(tmp_path / "nothing")


def test_missing_camera_json(rec):
    (rec / "camera.json").unlink()
    with pytest.raises(SourceError, match=r"camera\.json: file not found"):
        RecordingSource(rec)


def test_missing_camera_field(rec):
    _edit_camera(rec, depth_scale=None)
    with pytest.raises(SourceError, match=r"camera\.json: missing field\(s\) 'depth_scale'"):
        RecordingSource(rec)


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"fx": -500.0}, r"focal lengths must be positive, got fx=-500"),
        ({"fy": "525"}, r"'fy'.* must be finite numbers"),
        ({"width": 0}, r"'width' must be a positive integer"),
        ({"cx": 400.0}, r"principal point cx=400.0 lies outside"),
        ({"depth_scale": 0}, r"'depth_scale' .* must be positive"),
    ],
)
def test_bad_intrinsics(rec, changes, message):
    _edit_camera(rec, **changes)
    with pytest.raises(SourceError, match=message) as exc:
        RecordingSource(rec)
    assert "camera.json" in str(exc.value)


def test_malformed_camera_json(rec):
    (rec / "camera.json").write_text('{"width": 40,\n "height": }')
    with pytest.raises(SourceError, match=r"camera\.json: malformed JSON at line 2"):
        RecordingSource(rec)


def test_malformed_frames_line(rec):
    lines = (rec / "frames.jsonl").read_text().splitlines()
    lines[1] = lines[1][:-5]
    (rec / "frames.jsonl").write_text("\n".join(lines) + "\n")
    with pytest.raises(SourceError, match=r"frames\.jsonl, line 2: malformed JSON"):
        RecordingSource(rec)


@pytest.mark.parametrize(
    "line, message",
    [
        ({"index": 5, "t": 0.5}, r"line 4: missing field 'color'"),
        ({"index": 0, "t": 0.5, "color": "color/000000.png"}, r"line 4: duplicate frame index 0"),
        ({"index": 3, "t": "soon", "color": "color/000000.png"}, r"line 4: 't' must be a finite number"),
        ({"index": -1, "t": 0.3, "color": "color/000000.png"}, r"line 4: 'index' must be a non-negative integer"),
    ],
)
def test_bad_frames_fields(rec, line, message):
    with open(rec / "frames.jsonl", "a") as f:
        f.write(json.dumps(line) + "\n")
    with pytest.raises(SourceError, match=message):
        RecordingSource(rec)


def test_empty_frames(rec):
    (rec / "frames.jsonl").write_text("\n")
    with pytest.raises(SourceError, match=r"frames\.jsonl: no frames"):
        RecordingSource(rec)


def test_missing_colour_file_names_file_and_frame(rec):
    (rec / "color" / "000001.png").unlink()
    src = RecordingSource(rec)  # opening is lazy about images
    with pytest.raises(SourceError, match=r"frame 1: colour image not found: .*color/000001\.png"):
        src.read(1)
    with pytest.raises(SourceError, match=r"frame 1"):
        src.check()


def test_corrupt_png_during_iteration_can_be_skipped(rec):
    data = (rec / "depth" / "000001.png").read_bytes()
    (rec / "depth" / "000001.png").write_bytes(data[: len(data) // 3])
    src = RecordingSource(rec)
    it = iter(src)
    assert next(it).index == 0
    with pytest.raises(SourceError, match=r"frame 1: depth image .*depth/000001\.png is corrupt"):
        next(it)
    assert next(it).index == 2  # the iterator continues after a bad frame
    with pytest.raises(StopIteration):
        next(it)


def test_garbage_colour_file(rec):
    (rec / "color" / "000002.png").write_bytes(b"not a png at all")
    with pytest.raises(SourceError, match=r"frame 2: colour image .*000002\.png is corrupt"):
        RecordingSource(rec).read(2)


def test_8bit_depth_rejected(rec):
    cv2.imwrite(str(rec / "depth" / "000000.png"), np.full((30, 40), 100, np.uint8))
    with pytest.raises(SourceError, match=r"frame 0: depth image .*000000\.png must be 16-bit \(uint16\), got uint8"):
        RecordingSource(rec).read(0)


def test_wrong_size_depth_and_colour(rec):
    cv2.imwrite(str(rec / "depth" / "000000.png"), np.full((15, 20), 100, np.uint16))
    cv2.imwrite(str(rec / "color" / "000001.png"), np.zeros((15, 20, 3), np.uint8))
    src = RecordingSource(rec)
    with pytest.raises(SourceError, match=r"frame 0: depth image .* is 20x15, camera\.json says 40x30"):
        src.read(0)
    with pytest.raises(SourceError, match=r"frame 1: colour image .* is 20x15, camera\.json says 40x30"):
        src.read(1)


def test_multichannel_depth_rejected(rec):
    cv2.imwrite(str(rec / "depth" / "000000.png"), np.zeros((30, 40, 3), np.uint16))
    with pytest.raises(SourceError, match=r"frame 0: depth image .* must be single-channel"):
        RecordingSource(rec).read(0)


def test_bad_events_and_groundtruth_lines(rec):
    (rec / "events.jsonl").write_text('{"t": 1.0, "type": "connected", "parts": ["a", "b"]}\n'
                                      '{"t": 2.0, "type": "merged", "parts": ["a", "b"]}\n')
    with pytest.raises(SourceError, match=r"events\.jsonl, line 2: .*type must be one of"):
        RecordingSource(rec)
    (rec / "events.jsonl").unlink()
    (rec / "groundtruth.jsonl").write_text('{"index": 0, "poses": {"a": {"t": [0, 0, 1], "q": [0, 0, 0, 0]}}}\n')
    with pytest.raises(SourceError, match=r"groundtruth\.jsonl, line 1: bad pose of 'a'"):
        RecordingSource(rec)
