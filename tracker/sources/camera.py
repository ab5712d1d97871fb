"""Live RGB-D capture through OpenCV, without vendor SDKs: :class:`CameraSource` (``camera:<colour>[,<depth>]``).

How a camera is opened, in this order:

1. ``camera:<colour>,<depth>``: colour from ``cv2.VideoCapture(colour, cv2.CAP_V4L2)``; depth from a depth
   camera that exposes its depth stream as a V4L2/UVC video device (Intel RealSense D400 cameras do, as
   16-bit ``Z16`` frames), opened through OpenCV's V4L2 backend in raw mode (``CAP_PROP_CONVERT_RGB = 0``,
   FOURCC ``'Z16 '``) and reshaped to ``uint16`` H×W. Intrinsics of both cameras, the depth scale and the
   depth-to-colour transform come from a calibration file (:class:`CameraCalibration`); depth is registered
   to the colour image by :func:`tracker.sources.depth_registration.register_depth`. The two streams are
   paired by timestamp (nearest within ``pair_tolerance`` seconds, :class:`FramePairer`).
2. ``camera:<index>`` alone: only where the installed OpenCV has the OpenNI2 or Orbbec (``CAP_OBSENSOR``)
   backend, one device delivers colour and registered depth (``CAP_OPENNI_BGR_IMAGE`` /
   ``CAP_OPENNI_DEPTH_MAP``, resp. the OBSENSOR equivalents). The PyPI OpenCV wheels have neither, so this
   form normally fails with a :class:`SourceError` that lists what was tried and what to use instead.

A device that stops delivering frames is reported (``log`` warning, :attr:`CameraSource.status`) and
re-opened with exponential backoff by its reader thread; iteration simply waits meanwhile.

Units: depth in metres (``uint16 × depth_scale``, 0 → NaN), timestamps in seconds since the first frame.
"""

from __future__ import annotations

import glob
import json
import logging
import math
import queue
import re
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from tracker.frame import Frame
from tracker.geometry.camera import Intrinsics
from tracker.sources.base import FrameSource, SourceError
from tracker.sources.depth_registration import register_depth

log = logging.getLogger(__name__)

ALTERNATIVES = "use the simulated table (--source sim:guess-2) or a recording (--source recording:DIR) instead"
"""What the errors suggest when no camera can be used."""

Z16 = "Z16 "
"""FOURCC of 16-bit depth frames on UVC/V4L2 depth cameras (RealSense D400: one uint16 per pixel, little-endian)."""


# ----------------------------------------------------------------------------------------------------------
# calibration file


def _intrinsics_from(d: Any, where: str) -> Intrinsics:
    if not isinstance(d, dict):
        raise SourceError(f"{where}: expected an object with width, height, fx, fy, cx, cy")
    try:
        return Intrinsics.from_dict(d)
    except ValueError as exc:
        raise SourceError(f"{where}: {exc}") from exc


@dataclass(frozen=True)
class CameraCalibration:
    """Calibration of a colour + depth camera pair, loaded from JSON::

        {
          "color": {"width": 640, "height": 480, "fx": 615.0, "fy": 615.0, "cx": 320.0, "cy": 240.0},
          "depth": {"width": 640, "height": 480, "fx": 385.0, "fy": 385.0, "cx": 320.0, "cy": 240.0},
          "depth_scale": 0.001,
          "depth_to_color": [[1, 0, 0, 0.015], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
        }

    * ``color`` / ``depth``: pinhole intrinsics (pixels) of the undistorted images; ``depth`` may be omitted
      when the depth stream is already registered to colour (OpenNI2 / Orbbec backends).
    * ``depth_scale``: metres per raw depth unit (RealSense default 0.001).
    * ``depth_to_color``: 4×4 rigid transform (metres) mapping points in the depth camera frame to the colour
      camera frame (x right, y down, z forward); identity when omitted.
    """

    color: Intrinsics
    depth: Intrinsics | None = None
    depth_scale: float = 0.001
    depth_to_color: np.ndarray = field(default_factory=lambda: np.eye(4))

    @staticmethod
    def from_dict(d: Any, where: str = "calibration") -> CameraCalibration:
        if not isinstance(d, dict):
            raise SourceError(f"{where}: expected a JSON object")
        if "color" not in d:
            raise SourceError(f"{where}: missing field 'color' (colour intrinsics)")
        color = _intrinsics_from(d["color"], f"{where}, field 'color'")
        depth = _intrinsics_from(d["depth"], f"{where}, field 'depth'") if d.get("depth") is not None else None
        scale = d.get("depth_scale", 0.001)
        if not (isinstance(scale, int | float) and not isinstance(scale, bool) and math.isfinite(scale) and scale > 0):
            raise SourceError(f"{where}: 'depth_scale' must be a positive number of metres per unit, got {scale!r}")
        T = d.get("depth_to_color", np.eye(4).tolist())
        try:
            T = np.asarray(T, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise SourceError(f"{where}: 'depth_to_color' must be a 4x4 matrix of numbers") from exc
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise SourceError(f"{where}: 'depth_to_color' must be a 4x4 matrix of finite numbers, got shape {T.shape}")
        R = T[:3, :3]
        rigid = np.allclose(T[3], [0, 0, 0, 1]) and np.allclose(R @ R.T, np.eye(3), atol=1e-3) and np.linalg.det(R) > 0
        if not rigid:
            raise SourceError(f"{where}: 'depth_to_color' must be a rigid transform (rotation + translation, "
                              "last row 0 0 0 1)")
        return CameraCalibration(color, depth, float(scale), T)

    @staticmethod
    def load(path: str | Path) -> CameraCalibration:
        path = Path(path)
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError as exc:
            raise SourceError(f"calibration file not found: {path}") from exc
        except json.JSONDecodeError as exc:
            raise SourceError(f"{path}: malformed JSON at line {exc.lineno}: {exc.msg}") from exc
        return CameraCalibration.from_dict(data, str(path))

    def to_dict(self) -> dict:
        return {
            "color": self.color.to_dict(),
            "depth": None if self.depth is None else self.depth.to_dict(),
            "depth_scale": self.depth_scale,
            "depth_to_color": np.asarray(self.depth_to_color).tolist(),
        }


# ----------------------------------------------------------------------------------------------------------
# small pure helpers


def parse_camera_spec(spec: str) -> tuple[int | str, int | str | None]:
    """``"0"`` → ``(0, None)``; ``"4,2"`` → ``(4, 2)``; device paths (``/dev/video4``) are kept as strings."""

    def one(s: str) -> int | str:
        s = s.strip()
        if not s:
            raise ValueError(f"camera spec {spec!r}: empty device; expected camera:<colour>[,<depth>]")
        return int(s) if s.isdigit() else s

    parts = str(spec).split(",")
    if len(parts) > 2:
        raise ValueError(f"camera spec {spec!r}: expected camera:<colour>[,<depth>] (device indices or paths)")
    return one(parts[0]), (one(parts[1]) if len(parts) == 2 else None)


def device_path(device: int | str) -> str:
    return f"/dev/video{device}" if isinstance(device, int) else device


def list_video_devices() -> list[str]:
    """The ``/dev/video*`` device nodes present, in numeric order."""

    def key(p: str) -> tuple[int, str]:
        m = re.search(r"(\d+)$", p)
        return (int(m.group(1)) if m else 1 << 30, p)

    return sorted(glob.glob("/dev/video*"), key=key)


def depth_backends() -> dict[str, bool]:
    """Which OpenCV backends that deliver depth themselves are built into the installed ``cv2``."""
    try:
        names = set(cv2.videoio_registry.getCameraBackends())
    except Exception:  # noqa: BLE001 - very old OpenCV without the registry
        names = set()
    return {"OpenNI2": cv2.CAP_OPENNI2 in names, "Orbbec": getattr(cv2, "CAP_OBSENSOR", -1) in names}


def fourcc_to_str(value: float) -> str:
    v = int(value)
    return "".join(chr((v >> (8 * i)) & 0xFF) for i in range(4))


def decode_z16(raw: np.ndarray, width: int, height: int) -> np.ndarray:
    """A raw ``Z16`` buffer (as OpenCV returns it with ``CONVERT_RGB = 0``) → ``uint16`` height×width.

    Accepts the buffer in any shape/dtype (bytes are what count), with or without row padding.
    """
    buf = np.ascontiguousarray(raw).view(np.uint8).reshape(-1)
    need = width * height * 2
    if buf.size == need:
        return buf.view("<u2").reshape(height, width).astype(np.uint16)
    if buf.size > need and buf.size % height == 0 and (buf.size // height) >= 2 * width:
        stride = buf.size // height
        rows = buf.reshape(height, stride)[:, : 2 * width]
        return np.ascontiguousarray(rows).view("<u2").reshape(height, width).astype(np.uint16)
    raise SourceError(f"depth frame has {buf.size} bytes, expected {need} for {width}x{height} Z16")


# ----------------------------------------------------------------------------------------------------------
# pairing by timestamp


class FramePairer:
    """Pair colour and depth frames arriving separately by nearest timestamp within ``tolerance`` seconds.

    Each stream must arrive in time order. A colour frame is paired with the depth frame nearest in time
    once that choice can no longer improve (a depth frame at or after it has arrived, or a newer colour
    frame has); each depth frame is used at most once; colour frames without a depth frame within the
    tolerance are dropped (counted in :attr:`dropped_color`).
    """

    def __init__(self, tolerance: float = 0.02, max_buffer: int = 16) -> None:
        self.tolerance = float(tolerance)
        self._color: deque = deque(maxlen=max_buffer)
        self._depth: deque = deque(maxlen=max_buffer)
        self.dropped_color = 0
        self._lock = threading.Lock()

    def add_color(self, t: float, image: Any) -> None:
        with self._lock:
            self._color.append((t, image))

    def add_depth(self, t: float, image: Any) -> None:
        with self._lock:
            self._depth.append((t, image))

    def pop(self) -> tuple[float, Any, float, Any] | None:
        """The next pair ``(t_color, colour, t_depth, depth)``, or ``None`` if none is ready yet."""
        with self._lock:
            while self._color:
                tc, color = self._color[0]
                if not self._depth:
                    return None
                newest = self._depth[-1][0]
                if newest < tc and tc - newest <= self.tolerance and len(self._color) == 1:
                    return None  # a nearer depth frame may still come
                j = min(range(len(self._depth)), key=lambda k: abs(self._depth[k][0] - tc))
                td, depth = self._depth[j]
                if abs(td - tc) <= self.tolerance:
                    self._color.popleft()
                    for _ in range(j + 1):
                        self._depth.popleft()
                    return tc, color, td, depth
                if newest < tc:  # every buffered depth frame is too old for this and later colour frames
                    self._depth.clear()
                    return None
                self._color.popleft()  # no depth frame near this colour frame: drop it
                self.dropped_color += 1
            return None


def pair_by_timestamp(color_times, depth_times, tolerance: float = 0.02) -> list[tuple[int, int]]:
    """Offline pairing of two sorted timestamp lists; ``[(colour_index, depth_index), ...]``."""
    events = sorted([(t, 0, i) for i, t in enumerate(color_times)] + [(t, 1, i) for i, t in enumerate(depth_times)])
    pairer = FramePairer(tolerance, max_buffer=max(16, len(color_times) + len(depth_times)))
    out = []
    for t, kind, i in events:
        (pairer.add_color if kind == 0 else pairer.add_depth)(t, i)
        while (p := pairer.pop()) is not None:
            out.append((p[1], p[3]))
    pairer.add_color(math.inf, None)  # flush: a colour frame after everything
    while (p := pairer.pop()) is not None:
        if p[1] is not None:
            out.append((p[1], p[3]))
    return out


# ----------------------------------------------------------------------------------------------------------
# devices and reader threads

CaptureFactory = Callable[..., Any]
"""``factory(device, api) -> capture`` with the ``cv2.VideoCapture`` methods; ``cv2.VideoCapture`` by default."""


@dataclass
class _Device:
    """One opened (or re-openable) capture device and how to read it."""

    label: str  # e.g. "colour /dev/video4 (V4L2)"
    kind: str  # "color", "depth" or "rgbd"
    opener: Callable[[], Any]
    reader: Callable[[Any], tuple[float, Any, Any]]  # cap -> (t, colour or None, depth or None)
    cap: Any = None


class CameraSource(FrameSource):
    """Live RGB-D frames from OpenCV capture devices (see the module docstring for what is tried).

    * ``spec``: ``"<colour>"`` or ``"<colour>,<depth>"``, device indices (``/dev/videoN``) or paths.
    * ``calibration``: path of a calibration JSON (:class:`CameraCalibration`), or a loaded one; required
      with a separate depth device, optional with OpenNI2/Orbbec (then intrinsics come from the device).
    * ``fps``: requested frame rate; ``pair_tolerance``: seconds between paired colour and depth frames.
    * ``retry_delay`` / ``max_retry_delay``: reconnect backoff in seconds (doubling).
    * ``capture_factory``: replaces ``cv2.VideoCapture`` (tests use fake devices).
    * ``read_timeout``: if set, iteration raises :class:`SourceError` after this many seconds without a
      frame (default: wait for the device to come back).

    :attr:`status` is ``"streaming"``, ``"reconnecting: ..."`` or ``"closed"``; :attr:`last_error` holds the
    last problem reported. Iteration yields frames until :meth:`close`.
    """

    def __init__(
        self,
        spec: str,
        calibration: str | Path | CameraCalibration | None = None,
        fps: float = 30.0,
        pair_tolerance: float = 0.02,
        retry_delay: float = 0.5,
        max_retry_delay: float = 8.0,
        capture_factory: CaptureFactory | None = None,
        read_timeout: float | None = None,
    ) -> None:
        self.spec = str(spec)
        self.name = f"camera:{self.spec}"
        self.color_device, self.depth_device = parse_camera_spec(self.spec)
        if calibration is None or isinstance(calibration, CameraCalibration):
            self.calibration = calibration
        else:
            self.calibration = CameraCalibration.load(calibration)
        self.fps = float(fps)
        self.retry_delay = float(retry_delay)
        self.max_retry_delay = float(max_retry_delay)
        self._factory = capture_factory or cv2.VideoCapture
        self.read_timeout = read_timeout
        self.status = "opening"
        self.last_error: str | None = None
        self.backend = ""
        self._pairer = FramePairer(pair_tolerance)
        self._out: queue.Queue = queue.Queue(maxsize=4)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._device_status: dict[str, str] = {}
        self._intrinsics: Intrinsics | None = None
        self._devices = self._open_devices()
        self.status = "streaming"
        for dev in self._devices:
            th = threading.Thread(target=self._run_device, args=(dev,), name=f"camera-{dev.kind}", daemon=True)
            th.start()
            self._threads.append(th)

    # --- opening -----------------------------------------------------------------------------------------

    def _open_devices(self) -> list[_Device]:
        tried: list[str] = []
        present = list_video_devices()
        present_txt = ", ".join(present) if present else "none (no /dev/video* devices on this machine)"
        if self.depth_device is not None:
            if self.calibration is None or self.calibration.depth is None:
                raise SourceError(
                    f"{self.name}: a separate depth device needs a calibration file with colour and depth "
                    "intrinsics, depth_scale and depth_to_color (--calibration FILE; format in README 'Sources')"
                )
            color = self._v4l2_color_device(tried)
            depth = self._v4l2_depth_device(tried)
            if color is None or depth is None:
                for dev in (color, depth):
                    if dev is not None and dev.cap is not None:
                        dev.cap.release()
                raise SourceError(
                    f"{self.name}: cannot open the camera. Tried: {'; '.join(tried)}. "
                    f"Video devices present: {present_txt}. Check the device numbers (v4l2-ctl --list-devices; "
                    f"a RealSense shows several nodes, the depth one delivers Z16), or {ALTERNATIVES}."
                )
            self.backend = "V4L2 colour + V4L2 Z16 depth, registered to colour"
            self._intrinsics = self.calibration.color
            return [color, depth]
        backends = depth_backends()
        for name, api, color_id, depth_id in (
            ("OpenNI2", cv2.CAP_OPENNI2, cv2.CAP_OPENNI_BGR_IMAGE, cv2.CAP_OPENNI_DEPTH_MAP),
            ("Orbbec", getattr(cv2, "CAP_OBSENSOR", -1), getattr(cv2, "CAP_OBSENSOR_BGR_IMAGE", 1),
             getattr(cv2, "CAP_OBSENSOR_DEPTH_MAP", 0)),
        ):
            if not backends[name]:
                tried.append(f"{name} backend: not built into this OpenCV ({cv2.__version__})")
                continue
            dev = self._rgbd_device(name, api, color_id, depth_id, tried)
            if dev is not None:
                self.backend = f"{name} (colour + registered depth)"
                return [dev]
        raise SourceError(
            f"{self.name}: no depth stream could be opened. Tried: {'; '.join(tried)}. "
            f"Video devices present: {present_txt}. A depth camera that exposes depth as a V4L2 device "
            "(e.g. Intel RealSense D400, Z16) can be used as camera:<colour>,<depth> with --calibration FILE; "
            f"otherwise {ALTERNATIVES}."
        )

    def _open_capture(self, device: int | str, api: int):
        path = device_path(device)
        real_v4l2 = api == cv2.CAP_V4L2 and self._factory is cv2.VideoCapture
        if real_v4l2 and isinstance(device, int) and not Path(path).exists():
            return None, f"{path} does not exist"
        try:
            cap = self._factory(device, api)
        except Exception as exc:  # noqa: BLE001 - OpenCV raises cv2.error or others
            return None, f"{path}: {exc}"
        if cap is None or not cap.isOpened():
            return None, f"{path} could not be opened"
        return cap, ""

    def _v4l2_color_device(self, tried: list[str]) -> _Device | None:
        calib = self.calibration
        dev_id = self.color_device
        label = f"colour {device_path(dev_id)} (V4L2)"

        def opener():
            cap, why = self._open_capture(dev_id, cv2.CAP_V4L2)
            if cap is None:
                raise SourceError(f"{label}: {why}")
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, calib.color.width)
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, calib.color.height)
            cap.set(cv2.CAP_PROP_FPS, self.fps)
            w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
            if (w, h) != (calib.color.width, calib.color.height):
                cap.release()
                raise SourceError(f"{label}: delivers {w}x{h}, the calibration's colour intrinsics are for "
                                  f"{calib.color.width}x{calib.color.height}")
            return cap

        def reader(cap):
            if not cap.grab():
                raise OSError("grab failed")
            t = time.monotonic()
            ok, img = cap.retrieve()
            if not ok or img is None:
                raise OSError("retrieve failed")
            return t, _to_rgb(img), None

        return self._first_open(_Device(label, "color", opener, reader), tried)

    def _v4l2_depth_device(self, tried: list[str]) -> _Device | None:
        calib = self.calibration
        dint = calib.depth
        dev_id = self.depth_device
        label = f"depth {device_path(dev_id)} (V4L2, raw Z16)"

        def opener():
            cap, why = self._open_capture(dev_id, cv2.CAP_V4L2)
            if cap is None:
                raise SourceError(f"{label}: {why}")
            cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*Z16))
            cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, dint.width)
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, dint.height)
            cap.set(cv2.CAP_PROP_FPS, self.fps)
            fmt = fourcc_to_str(cap.get(cv2.CAP_PROP_FOURCC))
            if fmt != Z16:
                cap.release()
                raise SourceError(f"{label}: delivers {fmt.strip() or 'unknown'!r} frames, not Z16 depth "
                                  "(is this the depth node of the camera?)")
            return cap

        def reader(cap):
            if not cap.grab():
                raise OSError("grab failed")
            t = time.monotonic()
            ok, raw = cap.retrieve()
            if not ok or raw is None:
                raise OSError("retrieve failed")
            return t, None, decode_z16(raw, dint.width, dint.height)

        return self._first_open(_Device(label, "depth", opener, reader), tried)

    def _rgbd_device(self, name: str, api: int, color_id: int, depth_id: int, tried: list[str]) -> _Device | None:
        dev_id = self.color_device
        label = f"{name} device {dev_id}"

        def opener():
            cap, why = self._open_capture(dev_id, api)
            if cap is None:
                raise SourceError(f"{label}: {why}")
            if name == "OpenNI2":
                cap.set(cv2.CAP_PROP_OPENNI_REGISTRATION, 1)  # depth registered to colour by the driver
            return cap

        def reader(cap):
            if not cap.grab():
                raise OSError("grab failed")
            t = time.monotonic()
            ok_c, bgr = cap.retrieve(None, color_id)
            ok_d, depth = cap.retrieve(None, depth_id)
            if not ok_c or not ok_d or bgr is None or depth is None:
                raise OSError("retrieve failed")
            return t, _to_rgb(bgr), np.asarray(depth, dtype=np.uint16)

        dev = self._first_open(_Device(label, "rgbd", opener, reader), tried)
        if dev is None:
            return None
        if self.calibration is not None:
            self._intrinsics = self.calibration.color
        else:
            self._intrinsics = self._device_intrinsics(name, dev.cap)
        return dev

    def _device_intrinsics(self, name: str, cap) -> Intrinsics:
        """Approximate intrinsics reported by an OpenNI2/Orbbec device (principal point at the centre for OpenNI2)."""
        w = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)) or 640
        h = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)) or 480
        if name == "OpenNI2":
            f = cap.get(cv2.CAP_OPENNI_DEPTH_GENERATOR + cv2.CAP_PROP_OPENNI_FOCAL_LENGTH)
            f = f if f and f > 0 else 525.0 * w / 640.0
            return Intrinsics(w, h, f, f, (w - 1) / 2.0, (h - 1) / 2.0)
        base = getattr(cv2, "CAP_PROP_OBSENSOR_INTRINSIC_FX", 26001)
        fx, fy, cx, cy = (cap.get(base + k) for k in range(4))
        if not (fx > 0 and fy > 0):
            fx = fy = 525.0 * w / 640.0
            cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
        return Intrinsics(w, h, fx, fy, cx, cy)

    def _first_open(self, dev: _Device, tried: list[str]) -> _Device | None:
        try:
            dev.cap = dev.opener()
        except SourceError as exc:
            tried.append(str(exc))
            return None
        self._device_status[dev.label] = "streaming"
        return dev

    # --- reader threads ----------------------------------------------------------------------------------

    def _report(self, dev: _Device, message: str) -> None:
        self._device_status[dev.label] = message
        self.last_error = f"{dev.label}: {message}"
        bad = {k: v for k, v in self._device_status.items() if v != "streaming"}
        self.status = "streaming" if not bad else "reconnecting: " + "; ".join(f"{k} {v}" for k, v in bad.items())

    def _run_device(self, dev: _Device) -> None:
        delay = self.retry_delay
        failures = 0
        while not self._stop.is_set():
            if dev.cap is None:
                try:
                    dev.cap = dev.opener()
                except SourceError as exc:
                    self._report(dev, f"lost, re-open failed ({exc}); retrying in {delay:.1f} s")
                    log.warning("%s", self.last_error)
                    self._stop.wait(delay)
                    delay = min(delay * 2.0, self.max_retry_delay)
                    continue
                log.info("%s: re-opened", dev.label)
                self._report(dev, "streaming")
                delay = self.retry_delay
                failures = 0
            try:
                t, color, depth = dev.reader(dev.cap)
            except (OSError, SourceError, cv2.error) as exc:
                failures += 1
                if failures >= 3:
                    self._report(dev, f"lost ({exc}); re-opening")
                    log.warning("%s", self.last_error)
                    try:
                        dev.cap.release()
                    except Exception:  # noqa: BLE001 - a vanished device may fail to release
                        pass
                    dev.cap = None
                else:
                    self._stop.wait(0.01)
                continue
            failures = 0
            if dev.kind == "rgbd":
                self._emit(t, color, t, depth)
            else:
                if dev.kind == "color":
                    self._pairer.add_color(t, color)
                else:
                    self._pairer.add_depth(t, depth)
                while (p := self._pairer.pop()) is not None:
                    self._emit(*p)
        if dev.cap is not None:
            dev.cap.release()
            dev.cap = None

    def _emit(self, tc: float, color: np.ndarray, td: float, depth_units: np.ndarray | None) -> None:
        item = (tc, color, td, depth_units)
        while True:
            try:
                self._out.put_nowait(item)
                return
            except queue.Full:
                try:
                    self._out.get_nowait()  # live: keep the freshest frames
                except queue.Empty:
                    pass

    # --- FrameSource -------------------------------------------------------------------------------------

    @property
    def intrinsics(self) -> Intrinsics:
        return self._intrinsics

    @property
    def depth_scale(self) -> float:
        return self.calibration.depth_scale if self.calibration is not None else 0.001

    def _depth_metres(self, units: np.ndarray) -> np.ndarray:
        d = units.astype(np.float32) * np.float32(self.depth_scale)
        d[units == 0] = np.nan
        calib = self.calibration
        if calib is not None and calib.depth is not None and self.depth_device is not None:
            d = register_depth(d, calib.depth, calib.color, calib.depth_to_color)
        return d

    def __iter__(self) -> Iterator[Frame]:
        index = 0
        t0 = None
        last = time.monotonic()
        while not self._stop.is_set():
            try:
                tc, color, td, units = self._out.get(timeout=0.1)
            except queue.Empty:
                if self.read_timeout is not None and time.monotonic() - last > self.read_timeout:
                    raise SourceError(f"{self.name}: no frame for {self.read_timeout:.1f} s ({self.status})") from None
                continue
            last = time.monotonic()
            if t0 is None:
                t0 = tc
            intr = self._intrinsics
            if color.shape[:2] != (intr.height, intr.width):
                h, w = color.shape[:2]
                self.last_error = f"colour frame is {w}x{h}, expected {intr.width}x{intr.height}"
                log.warning("%s: %s; frame skipped", self.name, self.last_error)
                continue
            depth = self._depth_metres(units) if units is not None else None
            if depth is not None and depth.shape != color.shape[:2]:
                depth = cv2.resize(depth, (intr.width, intr.height), interpolation=cv2.INTER_NEAREST)
            meta = {"depth_time_offset": float(td - tc), "camera_status": self.status}
            yield Frame(index, float(tc - t0), color, depth, intr, meta)
            index += 1

    def metadata(self) -> dict[str, Any]:
        md = super().metadata()
        md.update(backend=self.backend, status=self.status, depth_scale=self.depth_scale,
                  dropped_color_frames=self._pairer.dropped_color)
        return md

    def close(self) -> None:
        self._stop.set()
        for th in self._threads:
            th.join(timeout=2.0)
        self._threads = []
        self.status = "closed"


def _to_rgb(img: np.ndarray) -> np.ndarray:
    img = np.asarray(img)
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    if img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
