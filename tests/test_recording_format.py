"""Recording reader/writer: real recordings, bit-exact round trips, objects.json, ground truth and events."""

from __future__ import annotations

import filecmp
import json
from pathlib import Path

import numpy as np
import pytest
from shared_data import REAL, needs_shared

from tracker.assembly.events import ConnectionEvent
from tracker.frame import Frame
from tracker.geometry.camera import Intrinsics
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose
from tracker.sources.base import SourceError
from tracker.sources.recording import (
    RecordingSource,
    RecordingWriter,
    depth_metres_to_units,
    depth_units_to_metres,
)

SMALL = Intrinsics(64, 48, 60.0, 61.0, 31.5, 23.5)


def synthetic_frame(i: int, rng: np.random.Generator, intr: Intrinsics = SMALL, t: float | None = None) -> Frame:
    color = rng.integers(0, 256, size=(intr.height, intr.width, 3), dtype=np.uint8)
    depth = rng.uniform(0.3, 2.0, size=(intr.height, intr.width)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.1] = np.nan
    return Frame(i, i / 30.0 if t is None else t, color, depth, intr)


# --- real recordings ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "name, n_frames, fx, has_depth",
    [("visp-cube-desk", 10, 614.9616699219, True), ("jenga", 2, 302.754, False), ("tum-desk", 1, 525.0, True)],
)
@needs_shared
def test_real_recordings_read(name, n_frames, fx, has_depth):
    import cv2

    src = RecordingSource(REAL / name)
    assert len(src) == n_frames
    assert (src.intrinsics.width, src.intrinsics.height) == (640, 480)
    assert src.intrinsics.fx == pytest.approx(fx)
    assert src.depth_scale == pytest.approx(0.001)
    frames = list(src)
    assert len(frames) == n_frames
    assert [f.index for f in frames] == list(range(n_frames))
    f = frames[0]
    assert f.color.dtype == np.uint8 and f.color.shape == (480, 480 * 4 // 3, 3)
    # colour is RGB: matches the BGR file with channels swapped
    bgr = cv2.imread(str(REAL / name / "color" / "000000.png"), cv2.IMREAD_COLOR)
    np.testing.assert_array_equal(f.color, bgr[:, :, ::-1])
    raw = cv2.imread(str(REAL / name / "depth" / "000000.png"), cv2.IMREAD_UNCHANGED)
    assert f.depth.dtype == np.float32
    np.testing.assert_array_equal(np.isnan(f.depth), raw == 0)
    if has_depth:
        valid = f.depth[np.isfinite(f.depth)]
        assert valid.size > 0.5 * f.depth.size
        assert 0.1 < valid.min() and valid.max() < 10.0
        np.testing.assert_allclose(valid, raw[raw > 0] * 0.001, rtol=1e-6)
    else:
        assert not f.has_depth
    assert src.events == [] and src.groundtruth(0) is None
    assert src.metadata()["n_frames"] == n_frames


@needs_shared
def test_visp_objects_without_pose():
    src = RecordingSource(REAL / "visp-cube-desk")
    assert [p.name for p in src.parts] == ["cube"]
    assert src.parts[0].box == (0.042, 0.042, 0.042) and src.parts[0].color is None
    assert src.initial_poses == {}


@needs_shared
def test_rewriting_real_recording_reproduces_files(tmp_path):
    src = RecordingSource(REAL / "visp-cube-desk")
    with RecordingWriter(tmp_path / "a", src.intrinsics, src.depth_scale, parts=src.parts) as w:
        for f in src:
            w.write(f)
    for name in ("camera.json", "frames.jsonl", "objects.json"):
        assert filecmp.cmp(REAL / "visp-cube-desk" / name, tmp_path / "a" / name, shallow=False), name
    a = RecordingSource(tmp_path / "a")
    for i in range(len(src)):
        fa, fs = a.read(i), src.read(i)
        np.testing.assert_array_equal(fa.color, fs.color)
        np.testing.assert_array_equal(fa.depth, fs.depth)  # NaN positions and values identical
    # a second generation is byte-identical to the first (PNG encoding is deterministic)
    with RecordingWriter(tmp_path / "b", a.intrinsics, a.depth_scale, parts=a.parts) as w:
        for f in a:
            w.write(f)
    cmp = filecmp.dircmp(tmp_path / "a", tmp_path / "b")
    assert not cmp.diff_files and not cmp.left_only and not cmp.right_only
    for sub in ("color", "depth"):
        m, mis, err = filecmp.cmpfiles(tmp_path / "a" / sub, tmp_path / "b" / sub, [f"{i:06d}.png" for i in range(10)],
                                       shallow=False)
        assert len(m) == 10 and not mis and not err


# --- synthetic round trips ---------------------------------------------------------------------------------


def test_round_trip_synthetic_bit_exact(tmp_path):
    rng = np.random.default_rng(3)
    frames = [synthetic_frame(i, rng) for i in range(4)]
    parts = [PartSpec.cube("red", "red"), PartSpec(name="plank", box=(0.1, 0.02, 0.05), color=None)]
    poses = {"red": Pose([0.01, 0.02, 0.7], [0.1, 0.2, 0.3, 0.9])}
    gts = [{"red": Pose([0.01 * i, 0.0, 0.7]), "plank": Pose([0.0, 0.1, 0.8])} for i in range(4)]
    with RecordingWriter(tmp_path, SMALL, depth_scale=0.0005, parts=parts, initial_poses=poses) as w:
        for f, gt in zip(frames, gts, strict=True):
            w.write(f, groundtruth=gt)
        w.write_event(0.05, "connected", ["red", "plank"])
        w.write_event(0.09, "disconnected", ("red", "plank"))
    src = RecordingSource(tmp_path)
    assert len(src) == 4 and src.intrinsics == SMALL and src.depth_scale == 0.0005
    for f, g in zip(frames, src, strict=True):
        assert g.index == f.index and g.timestamp == f.timestamp
        np.testing.assert_array_equal(g.color, f.color)
        np.testing.assert_array_equal(np.isnan(g.depth), np.isnan(f.depth))
        ok = np.isfinite(f.depth)
        # exact to the quantisation: |error| <= half a depth unit
        assert np.max(np.abs(g.depth[ok] - f.depth[ok])) <= 0.0005 / 2 + 1e-6
        np.testing.assert_array_equal(g.depth[ok], depth_units_to_metres(depth_metres_to_units(f.depth, 0.0005),
                                                                         0.0005)[ok])
    assert [p.name for p in src.parts] == ["red", "plank"]
    assert src.parts[0].color == (210, 30, 35) and src.parts[1].box == (0.1, 0.02, 0.05)
    assert set(src.initial_poses) == {"red"}
    np.testing.assert_allclose(src.initial_poses["red"].q, poses["red"].q)
    gt2 = src.groundtruth(2)
    np.testing.assert_allclose(gt2["red"].t, [0.02, 0.0, 0.7])
    assert src.read(2).meta["groundtruth"]["poses"]["plank"].t[1] == pytest.approx(0.1)
    assert src.events == [ConnectionEvent(0.05, "connected", ("red", "plank")),
                          ConnectionEvent(0.09, "disconnected", ("red", "plank"))]
    # write the read recording again: identical files
    with RecordingWriter(tmp_path / "again", src.intrinsics, src.depth_scale, src.parts, src.initial_poses) as w:
        for f in src:
            w.write(f, groundtruth=f.meta.get("groundtruth"))
        for ev in src.events:
            w.write_event(ev.t, ev.type, ev.parts)
    for name in ("camera.json", "frames.jsonl", "objects.json", "groundtruth.jsonl", "events.jsonl",
                 "color/000003.png", "depth/000003.png"):
        assert filecmp.cmp(tmp_path / name, tmp_path / "again" / name, shallow=False), name


def test_depth_quantisation_rules():
    d = np.array([[np.nan, 0.0, -1.0, 0.0004, 0.0006, 1.2346, 65.535, 65.5356, 100.0]], np.float32)
    u = depth_metres_to_units(d, 0.001)
    assert u.dtype == np.uint16
    assert u.tolist() == [[0, 0, 0, 0, 1, 1235, 65535, 0, 0]]
    m = depth_units_to_metres(np.array([[0, 1, 65535]], np.uint16), 0.001)
    assert np.isnan(m[0, 0]) and m[0, 1] == np.float32(0.001) and m[0, 2] == np.float32(65.535)


def test_depth_lookup_table_is_the_per_pixel_conversion():
    """Every uint16 value converts to ``float32(value × depth_scale)`` (the product in float64), 0 to NaN, for
    several scales."""
    raw = np.arange(65536, dtype=np.uint16).reshape(256, 256)
    for scale in (0.001, 0.0005, 0.000125, 1e-4 / 3.0):
        ref = (raw.astype(np.float64) * scale).astype(np.float32)
        ref[raw == 0] = np.nan
        got = depth_units_to_metres(raw, scale)
        assert got.dtype == np.float32 and got.shape == raw.shape
        assert np.array_equal(got, ref, equal_nan=True)


def test_writer_stores_depth_unfiltered_and_reads_it_back(tmp_path):
    """The writer's depth PNGs have every row unfiltered (PNG filter type 0: they decode faster) and read back
    exactly."""
    import zlib

    rng = np.random.default_rng(2)
    f = synthetic_frame(0, rng)
    with RecordingWriter(tmp_path / "rec", SMALL) as w:
        w.write(f)
    data = (tmp_path / "rec" / "depth" / "000000.png").read_bytes()
    idat, pos = b"", 8
    while pos < len(data):
        n = int.from_bytes(data[pos:pos + 4], "big")
        if data[pos + 4:pos + 8] == b"IDAT":
            idat += data[pos + 8:pos + 8 + n]
        pos += 12 + n
    rows = zlib.decompress(idat)
    stride = 1 + 2 * SMALL.width  # filter byte + 16-bit grey pixels
    assert len(rows) == stride * SMALL.height
    assert all(rows[r * stride] == 0 for r in range(SMALL.height))
    back = RecordingSource(tmp_path / "rec").read(0)
    ok = np.isfinite(f.depth)
    np.testing.assert_array_equal(back.depth[ok], depth_units_to_metres(depth_metres_to_units(f.depth, 0.001),
                                                                        0.001)[ok])


def test_frame_without_depth_and_jpeg(tmp_path):
    rng = np.random.default_rng(1)
    f = synthetic_frame(0, rng)
    smooth = np.zeros_like(f.color)
    smooth[..., 0] = np.linspace(0, 255, SMALL.width, dtype=np.uint8)[None, :]
    f2 = Frame(0, 0.0, smooth, None, SMALL)
    with RecordingWriter(tmp_path, SMALL, color_format="jpg") as w:
        w.write(f2)
    line = json.loads((tmp_path / "frames.jsonl").read_text())
    assert line["color"] == "color/000000.jpg" and line["depth"] is None
    g = RecordingSource(tmp_path).read(0)
    assert g.depth is None
    assert np.abs(g.color.astype(int) - smooth.astype(int)).max() <= 8  # lossy but close


def test_loop_and_iteration(tmp_path):
    rng = np.random.default_rng(2)
    with RecordingWriter(tmp_path, SMALL) as w:
        for i in range(3):
            w.write(synthetic_frame(i, rng))
    src = RecordingSource(tmp_path, loop=True)
    it = iter(src)
    frames = [next(it) for _ in range(7)]
    assert [f.index for f in frames] == list(range(7))
    assert [f.meta["recording_position"] for f in frames] == [0, 1, 2, 0, 1, 2, 0]
    ts = [f.timestamp for f in frames]
    assert all(b > a for a, b in zip(ts, ts[1:], strict=False))
    np.testing.assert_array_equal(frames[3].color, frames[0].color)
    assert src.read(-1).index == 2
    with pytest.raises(IndexError):
        src.read(3)


def test_writer_refuses_existing_recording(tmp_path):
    with RecordingWriter(tmp_path, SMALL) as w:
        w.write(synthetic_frame(0, np.random.default_rng(0)))
    with pytest.raises(FileExistsError, match="already holds a recording"):
        RecordingWriter(tmp_path, SMALL)
    with pytest.raises(ValueError, match="connection event"):
        RecordingWriter(tmp_path / "x", SMALL).write_event(1.0, "glued", ["a", "b"])
    with pytest.raises(ValueError, match="differs"):
        RecordingWriter(tmp_path / "y", SMALL).write(synthetic_frame(0, np.random.default_rng(0),
                                                                     Intrinsics.default(32, 24)))


# --- objects.json ------------------------------------------------------------------------------------------


def _minimal_recording(root: Path, n: int = 2) -> None:
    with RecordingWriter(root, SMALL) as w:
        rng = np.random.default_rng(5)
        for i in range(n):
            w.write(synthetic_frame(i, rng))


def test_objects_box_mesh_and_missing_pose(tmp_path):
    _minimal_recording(tmp_path)
    (tmp_path / "models").mkdir()
    (tmp_path / "models" / "tet.obj").write_text(
        "v 0 0 0\nv 10 0 0\nv 0 10 0\nv 0 0 10\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
    )
    objects = {
        "objects": [
            {"name": "a", "shape": {"box": [0.036, 0.036, 0.036]}, "color": [255, 0, 0],
             "pose": {"t": [0, 0, 0.7], "q": [0, 0, 0, 1]}},
            {"name": "tet", "shape": {"mesh": "models/tet.obj", "scale": 0.01}, "color": None,
             "pose": {"t": [0.1, 0, 0.8], "q": [0, 0, 1, 0]}},
            {"name": "nopose", "shape": {"box": [0.02, 0.02, 0.1]}, "color": None},
        ]
    }
    (tmp_path / "objects.json").write_text(json.dumps(objects))
    src = RecordingSource(tmp_path)
    a, tet, nopose = src.parts
    assert a.box == (0.036, 0.036, 0.036) and a.color == (255, 0, 0)
    assert tet.box is None and tet.mesh_scale == 0.01
    mesh = tet.load_mesh()
    np.testing.assert_allclose(mesh.bounds, [[0, 0, 0], [0.1, 0.1, 0.1]])
    assert nopose.box == (0.02, 0.02, 0.1)
    assert set(src.initial_poses) == {"a", "tet"}
    np.testing.assert_allclose(src.initial_poses["tet"].t, [0.1, 0, 0.8])
    # the writer stores the mesh relative to the recording, and copies foreign meshes into meshes/
    with RecordingWriter(tmp_path / "copy", SMALL, parts=src.parts, initial_poses=src.initial_poses):
        pass
    written = json.loads((tmp_path / "copy" / "objects.json").read_text())["objects"]
    assert written[1]["shape"] == {"mesh": "meshes/tet.obj", "scale": 0.01}
    assert "pose" not in written[2]
    assert (tmp_path / "copy" / "meshes" / "tet.obj").read_text() == (tmp_path / "models" / "tet.obj").read_text()


@pytest.mark.parametrize(
    "objects, message",
    [
        ({"objects": [{"name": "a", "shape": {"mesh": "nope.obj"}}]}, r"object 0 \('a'\): mesh file not found"),
        ({"objects": [{"name": "a", "shape": {"box": [1, 2]}}]}, r"object 0 \('a'\): 'box' must be three"),
        ({"objects": [{"shape": {"box": [1, 2, 3]}}]}, r"object 0: missing or empty 'name'"),
        ({"objects": [{"name": "a", "shape": {"box": [1, 1, 1]}, "color": [300, 0, 0]}]}, r"'color' must be"),
        ({"objects": [{"name": "a", "shape": {"box": [1, 1, 1]}, "pose": {"t": [0, 0]}}]}, r"bad 'pose'"),
        ({"things": []}, r"expected \{\"objects\""),
    ],
)
def test_objects_errors(tmp_path, objects, message):
    _minimal_recording(tmp_path)
    (tmp_path / "objects.json").write_text(json.dumps(objects))
    with pytest.raises(SourceError, match=message) as exc:
        RecordingSource(tmp_path)
    assert "objects.json" in str(exc.value)


def test_overwrite_replaces_old_frames(tmp_path):
    rng = np.random.default_rng(4)
    with RecordingWriter(tmp_path, SMALL) as w:
        for i in range(3):
            w.write(synthetic_frame(i, rng))
    with RecordingWriter(tmp_path, SMALL, overwrite=True) as w:
        w.write(synthetic_frame(0, rng))
    assert sorted(p.name for p in (tmp_path / "color").iterdir()) == ["000000.png"]
    assert len(RecordingSource(tmp_path)) == 1
