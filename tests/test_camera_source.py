"""Live camera source without hardware: calibration files, Z16 decoding, pairing by timestamp, error messages
when no device exists, and the capture/reconnect logic driven by fake OpenCV capture objects."""

from __future__ import annotations

import json
import threading
import time

import cv2
import numpy as np
import pytest

from tracker.geometry.camera import Intrinsics
from tracker.sources import camera as camera_mod
from tracker.sources.base import SourceError
from tracker.sources.camera import (
    CameraCalibration,
    CameraSource,
    FramePairer,
    decode_z16,
    fourcc_to_str,
    pair_by_timestamp,
    parse_camera_spec,
)

COLOR = Intrinsics(32, 24, 30.0, 30.0, 15.5, 11.5)
DEPTH = Intrinsics(32, 24, 30.0, 30.0, 15.5, 11.5)


def calib_dict(**over) -> dict:
    d = {"color": COLOR.to_dict(), "depth": DEPTH.to_dict(), "depth_scale": 0.001,
         "depth_to_color": np.eye(4).tolist()}
    d.update(over)
    return d


# --- pure helpers ------------------------------------------------------------------------------------------


def test_parse_camera_spec():
    assert parse_camera_spec("0") == (0, None)
    assert parse_camera_spec("4,2") == (4, 2)
    assert parse_camera_spec("/dev/video4, /dev/video2") == ("/dev/video4", "/dev/video2")
    for bad in ("", "0,", "0,1,2"):
        with pytest.raises(ValueError, match="camera:<colour>"):
            parse_camera_spec(bad)


def test_calibration_load_and_errors(tmp_path):
    p = tmp_path / "cal.json"
    T = np.eye(4)
    T[:3, 3] = [0.015, 0, 0]
    p.write_text(json.dumps(calib_dict(depth_to_color=T.tolist(), depth_scale=0.0001)))
    cal = CameraCalibration.load(p)
    assert cal.color == COLOR and cal.depth == DEPTH and cal.depth_scale == 0.0001
    np.testing.assert_allclose(cal.depth_to_color, T)
    assert CameraCalibration.from_dict(cal.to_dict()).depth_scale == 0.0001

    cases = [
        ({k: v for k, v in calib_dict().items() if k != "color"}, "missing field 'color'"),
        (calib_dict(depth={**DEPTH.to_dict(), "fx": -1}), r"field 'depth'.*focal lengths must be positive"),
        (calib_dict(depth_scale=-0.001), "'depth_scale' must be a positive number"),
        (calib_dict(depth_to_color=np.eye(3).tolist()), "4x4 matrix"),
        (calib_dict(depth_to_color=(2 * np.eye(4)).tolist()), "rigid transform"),
    ]
    for data, message in cases:
        p.write_text(json.dumps(data))
        with pytest.raises(SourceError, match=message) as exc:
            CameraCalibration.load(p)
        assert str(p) in str(exc.value)
    with pytest.raises(SourceError, match="calibration file not found"):
        CameraCalibration.load(tmp_path / "none.json")


def test_decode_z16():
    depth = np.arange(6 * 4, dtype=np.uint16).reshape(4, 6) * 1000
    raw = np.frombuffer(depth.astype("<u2").tobytes(), np.uint8).reshape(1, -1)  # as OpenCV returns raw frames
    np.testing.assert_array_equal(decode_z16(raw, 6, 4), depth)
    padded = np.zeros((4, 16), np.uint8)  # 2 bytes of row padding per row
    padded[:, :12] = np.frombuffer(depth.astype("<u2").tobytes(), np.uint8).reshape(4, 12)
    np.testing.assert_array_equal(decode_z16(padded, 6, 4), depth)
    with pytest.raises(SourceError, match="expected 48 for 6x4 Z16"):
        decode_z16(np.zeros(40, np.uint8), 6, 4)


def test_fourcc_round_trip():
    assert fourcc_to_str(cv2.VideoWriter_fourcc(*"Z16 ")) == "Z16 "


def test_pairing_by_timestamp_with_jitter_and_drops():
    rng = np.random.default_rng(0)
    color_t = np.arange(60) / 30.0 + rng.normal(0, 0.002, 60)
    depth_t = np.arange(60) / 30.0 + 0.006 + rng.normal(0, 0.002, 60)
    depth_t = np.delete(depth_t, [10, 11, 12, 40])  # depth frames lost
    pairs = pair_by_timestamp(color_t, depth_t, tolerance=0.02)
    assert len({j for _, j in pairs}) == len(pairs)  # each depth frame at most once
    assert all(abs(color_t[i] - depth_t[j]) <= 0.02 for i, j in pairs)
    paired_colour = {i for i, _ in pairs}
    assert not paired_colour & {10, 11, 12}  # their depth frames are gone: no pairing with a neighbour's
    assert paired_colour == set(range(60)) - {10, 11, 12, 40}
    for i, j in pairs:  # nearest in time
        assert np.argmin(np.abs(depth_t - color_t[i])) == j


def test_pairer_waits_for_a_nearer_depth_frame():
    p = FramePairer(tolerance=0.02)
    p.add_color(1.000, "c0")
    p.add_depth(0.990, "d-early")
    assert p.pop() is None  # a depth frame at 1.000 might still come
    p.add_depth(1.001, "d0")
    assert p.pop() == (1.000, "c0", 1.001, "d0")
    p.add_color(2.0, "c1")
    p.add_depth(2.5, "d1")
    assert p.pop() is None and p.dropped_color == 1  # no depth near 2.0: colour dropped


# --- errors without devices --------------------------------------------------------------------------------


def test_no_video_devices_error_says_what_was_tried(tmp_path, monkeypatch):
    monkeypatch.setattr(camera_mod, "list_video_devices", lambda: [])
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(calib_dict()))
    # real cv2.VideoCapture on device paths that cannot exist on any machine
    with pytest.raises(SourceError) as exc:
        CameraSource("/dev/video-missing-4,/dev/video-missing-2", calibration=cal)
    msg = str(exc.value)
    assert "/dev/video-missing-4" in msg and "/dev/video-missing-2" in msg and "V4L2" in msg
    assert "no /dev/video* devices" in msg
    assert "sim:" in msg and "recording:" in msg


def test_index_of_absent_device(tmp_path, monkeypatch):
    monkeypatch.setattr(camera_mod, "list_video_devices", lambda: [])
    with pytest.raises(SourceError, match=r"/dev/video9997 does not exist.*/dev/video9998 does not exist"):
        CameraSource("9997,9998", calibration=CameraCalibration.from_dict(calib_dict()))


def test_colour_only_spec_without_depth_backends(monkeypatch):
    monkeypatch.setattr(camera_mod, "depth_backends", lambda: {"OpenNI2": False, "Orbbec": False})
    monkeypatch.setattr(camera_mod, "list_video_devices", lambda: ["/dev/video0"])
    with pytest.raises(SourceError) as exc:
        CameraSource("0")
    msg = str(exc.value)
    assert "no depth stream" in msg and "OpenNI2 backend: not built into this OpenCV" in msg
    assert "Orbbec backend: not built" in msg and "/dev/video0" in msg
    assert "camera:<colour>,<depth>" in msg and "sim:guess-2" in msg


def test_separate_depth_needs_calibration():
    with pytest.raises(SourceError, match="needs a calibration file"):
        CameraSource("0,2")


def test_depth_backends_reports_installed_opencv():
    b = camera_mod.depth_backends()
    assert set(b) == {"OpenNI2", "Orbbec"}
    assert b["OpenNI2"] == (cv2.CAP_OPENNI2 in cv2.videoio_registry.getCameraBackends())


# --- fake devices: capture, registration, reconnect ------------------------------------------------------


class FakeDevice:
    def __init__(self, kind: str, size=(32, 24), depth_units: int = 800):
        self.kind = kind  # "color", "z16", "yuyv", "rgbd"
        self.size = size
        self.alive = threading.Event()
        self.alive.set()
        self.depth_units = depth_units
        self.opens = 0
        self.frames = 0


class FakeCapture:
    def __init__(self, dev: FakeDevice | None, api: int):
        self.dev, self.api = dev, api
        self.props: dict[int, float] = {}
        self.opened = dev is not None and dev.alive.is_set()
        if self.opened:
            dev.opens += 1

    def isOpened(self):  # noqa: N802 - OpenCV's name
        return self.opened

    def set(self, prop, value):
        self.props[prop] = value
        return True

    def get(self, prop):
        w, h = self.dev.size
        if prop == cv2.CAP_PROP_FRAME_WIDTH:
            return w
        if prop == cv2.CAP_PROP_FRAME_HEIGHT:
            return h
        if prop == cv2.CAP_PROP_FOURCC:
            fmt = "Z16 " if self.dev.kind == "z16" else "YUYV"
            return float(cv2.VideoWriter_fourcc(*fmt))
        return 0.0

    def grab(self):
        if not self.dev.alive.is_set():
            return False
        time.sleep(0.004)
        self.dev.frames += 1
        return True

    def retrieve(self, image=None, flag=0):
        w, h = self.dev.size
        if self.dev.kind == "z16" or (self.dev.kind == "rgbd" and flag == cv2.CAP_OPENNI_DEPTH_MAP):
            d = np.full((h, w), self.dev.depth_units, np.uint16)
            d[0, 0] = 0
            if self.dev.kind == "rgbd":
                return True, d
            return True, np.frombuffer(d.astype("<u2").tobytes(), np.uint8).reshape(1, -1)
        bgr = np.zeros((h, w, 3), np.uint8)
        bgr[..., 0] = 200  # blue in BGR
        return True, bgr

    def release(self):
        self.opened = False


def factory_for(devices: dict):
    return lambda device, api: FakeCapture(devices.get(device), api)


def take(it, n):
    return [next(it) for _ in range(n)]


def test_v4l2_pair_gives_registered_depth_and_rgb():
    devices = {4: FakeDevice("color"), 2: FakeDevice("z16", depth_units=800)}
    T = np.eye(4)
    T[0, 3] = 0.0  # identity: registered depth equals the raw depth
    cal = CameraCalibration.from_dict(calib_dict(depth_to_color=T.tolist()))
    src = CameraSource("4,2", calibration=cal, capture_factory=factory_for(devices), read_timeout=5.0)
    try:
        frames = take(iter(src), 3)
    finally:
        src.close()
    assert src.status == "closed" and "V4L2" in src.backend
    f = frames[-1]
    assert f.intrinsics == COLOR and f.color.shape == (24, 32, 3)
    assert tuple(f.color[0, 0]) == (0, 0, 200)  # BGR -> RGB
    assert np.isnan(f.depth[0, 0]) and np.allclose(f.depth[1:, 1:], 0.8)
    assert [fr.index for fr in frames] == [0, 1, 2]
    assert frames[0].timestamp == 0.0 and frames[2].timestamp > frames[1].timestamp
    assert abs(f.meta["depth_time_offset"]) <= 0.02
    assert devices[2].opens == 1


def test_depth_device_that_is_not_z16():
    devices = {0: FakeDevice("color"), 1: FakeDevice("yuyv")}
    with pytest.raises(SourceError, match=r"depth /dev/video1 .* delivers 'YUYV' frames, not Z16"):
        CameraSource("0,1", calibration=CameraCalibration.from_dict(calib_dict()),
                     capture_factory=factory_for(devices))


def test_colour_size_must_match_calibration():
    devices = {0: FakeDevice("color", size=(64, 48)), 1: FakeDevice("z16")}
    with pytest.raises(SourceError, match=r"delivers 64x48, the calibration's colour intrinsics are for 32x24"):
        CameraSource("0,1", calibration=CameraCalibration.from_dict(calib_dict()),
                     capture_factory=factory_for(devices))


def test_camera_that_disappears_is_reported_and_reopened():
    devices = {0: FakeDevice("color"), 1: FakeDevice("z16")}
    src = CameraSource("0,1", calibration=CameraCalibration.from_dict(calib_dict()),
                       capture_factory=factory_for(devices), retry_delay=0.01, max_retry_delay=0.05,
                       read_timeout=5.0)
    try:
        it = iter(src)
        take(it, 2)
        devices[0].alive.clear()  # unplugged: grab fails and re-opening fails
        deadline = time.monotonic() + 5.0
        while not src.status.startswith("reconnecting") and time.monotonic() < deadline:
            time.sleep(0.01)
        assert src.status.startswith("reconnecting") and "/dev/video0" in src.status
        assert "/dev/video0" in src.last_error
        before = devices[0].opens  # a failed open does not count
        devices[0].alive.set()  # plugged back in
        # frames paired before the unplug may still be queued: read on until the device is open again
        frames = []
        deadline = time.monotonic() + 5.0
        while (devices[0].opens == before or src.status != "streaming") and time.monotonic() < deadline:
            frames.append(next(it))  # iteration continues, no exception
        frames += take(it, 2)
        assert devices[0].opens > before
        assert src.status == "streaming"
        assert [f.index for f in frames] == list(range(2, 2 + len(frames)))
    finally:
        src.close()


def test_read_timeout_when_camera_stays_away():
    devices = {0: FakeDevice("color"), 1: FakeDevice("z16")}
    src = CameraSource("0,1", calibration=CameraCalibration.from_dict(calib_dict()),
                       capture_factory=factory_for(devices), retry_delay=0.01, read_timeout=0.3)
    try:
        it = iter(src)
        take(it, 1)
        devices[1].alive.clear()
        with pytest.raises(SourceError, match=r"camera:0,1: no frame for 0.3 s"):
            take(it, 100)
    finally:
        src.close()


def test_openni2_backend_path(monkeypatch):
    monkeypatch.setattr(camera_mod, "depth_backends", lambda: {"OpenNI2": True, "Orbbec": False})
    devices = {0: FakeDevice("rgbd", depth_units=650)}
    src = CameraSource("0", capture_factory=factory_for(devices), read_timeout=5.0)
    try:
        f = take(iter(src), 1)[0]
    finally:
        src.close()
    assert src.backend.startswith("OpenNI2")
    assert f.intrinsics.width == 32 and f.intrinsics.fx == pytest.approx(525.0 * 32 / 640)
    assert np.isnan(f.depth[0, 0]) and np.allclose(f.depth[1:, 1:], 0.65)
