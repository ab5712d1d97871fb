"""What the pipeline knows after one frame: a plain value handed to the web app, recorders and scripts.

Units and frames: poses are camera-frame :class:`~tracker.geometry.pose.Pose` values (metres, Hamilton
quaternions ``[x, y, z, w]``); particle positions are camera-frame metres (float32); pixel boxes are
``[u0, v0, u1, v1]`` in the colour image; times are seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tracker.geometry.pose import Pose


def _finite_list(values: Any, ndigits: int = 5) -> list[float | None]:
    """A JSON-safe list of rounded floats (NaN and infinity become ``None``)."""
    out: list[float | None] = []
    for v in np.asarray(values, dtype=float).ravel():
        out.append(round(float(v), ndigits) if math.isfinite(v) else None)
    return out


@dataclass
class Snapshot:
    """The state after processing one frame.

    * ``frame_index``, ``time``: the frame's index and timestamp (seconds since the source started).
    * ``wall_time``: the frame's capture time as ``time.time()`` (for latency measurements): a paced
      simulator/recording frame's due time, when an unpaced frame's production started, when a camera
      frame arrived.
    * ``poses``: estimated part poses, camera frame.
    * ``particles``: per part, the particle positions ``(N, 3)`` float32, camera frame (not sent as JSON).
    * ``boxes``: per part, the pixel bounding box of its estimated pose projected into the colour image.
    * ``detections``: per part, colour detection ``{"center": [u, v] | None, "bbox": [x, y, w, h] | None,
      "score": float, "area": float}``.
    * ``connections``: list of ``{"first", "second", "state", ...}`` from the mode state.
    * ``mode``: the mode name; ``mode_state``: the mode's ``ModeState.to_dict()``; ``instruction``: the
      instruction or verdict to show in large type.
    * ``table``: ``{"normal": [3], "offset": float, "table_to_camera": Pose dict}`` or ``None``.
    * ``fps``: processed frames per second (moving average); ``timings``: seconds per stage.
    * ``source``: the source's metadata; ``errors``: messages about this frame (a stage that failed, a part
      automatic placement has not found yet).
    * ``carried``: names of the parts currently hidden inside a hand and moved with it (``[]`` when none).
    * ``hands``: the tracked hands when hand tracking is on (``[]`` otherwise): per hand ``{"id", "box": [u0, v0, u1,
      v1] px (end-exclusive), "score", "velocity": [du, dv] px/frame, "touching": [parts], "holding": [parts],
      "text", "position"}``, ``text`` e.g. "holding the red cube", ``position`` the camera-frame point (metres) of the
      box centre at the median depth of the hand's skin pixels or None (:meth:`tracker.hands.loop.HandLoop.hands`).
    * ``identical_parts``: parts of one colour told apart in the image from user-drawn boxes (the web app's
      :mod:`app.identical_parts`): per name ``{"bbox": [x, y, w, h], "center", "score", "seen"}``.
    * ``camera_pose``: the camera's pose in the world frame (camera → world; world = the first frame's camera
      frame) from the camera odometry (:mod:`tracker.odometry`), ``None`` when odometry is off;
      ``camera_pose_ok``: False when that pose was extrapolated rather than measured.
    """

    frame_index: int
    time: float
    wall_time: float = 0.0
    poses: dict[str, Pose] = field(default_factory=dict)
    particles: dict[str, np.ndarray] = field(default_factory=dict)
    boxes: dict[str, list[float]] = field(default_factory=dict)
    detections: dict[str, dict[str, Any]] = field(default_factory=dict)
    connections: list[dict[str, Any]] = field(default_factory=list)
    mode: str | None = None
    mode_state: dict[str, Any] = field(default_factory=dict)
    instruction: str = ""
    table: dict[str, Any] | None = None
    fps: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)
    source: dict[str, Any] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)
    carried: list[str] = field(default_factory=list)
    hands: list[dict[str, Any]] = field(default_factory=list)
    image_size: tuple[int, int] = (0, 0)
    identical_parts: dict[str, dict[str, Any]] = field(default_factory=dict)
    camera_pose: Pose | None = None
    camera_pose_ok: bool = True

    def to_dict(self, include_particles: bool = False) -> dict[str, Any]:
        """A JSON-able dictionary (particle clouds only when ``include_particles``)."""
        d: dict[str, Any] = {
            "frame_index": int(self.frame_index),
            "time": round(float(self.time), 4),
            "wall_time": float(self.wall_time),
            "poses": {name: {"t": _finite_list(p.t), "q": _finite_list(p.q)} for name, p in self.poses.items()},
            "boxes": {name: _finite_list(b, 1) for name, b in self.boxes.items()},
            "detections": self.detections,
            "connections": self.connections,
            "mode": self.mode,
            "mode_state": self.mode_state,
            "instruction": self.instruction,
            "table": self.table,
            "fps": round(float(self.fps), 2),
            "timings": {k: round(float(v), 5) for k, v in self.timings.items()},
            "source": self.source,
            "errors": list(self.errors),
            "carried": [str(n) for n in self.carried],
            "hands": self.hands,
            "image_size": list(self.image_size),
            "identical_parts": self.identical_parts,
            "camera_pose": None if self.camera_pose is None else {
                "t": _finite_list(self.camera_pose.t), "q": _finite_list(self.camera_pose.q),
                "ok": bool(self.camera_pose_ok)},
        }
        if include_particles:
            d["particles"] = {name: np.asarray(p, np.float32).round(4).tolist() for name, p in self.particles.items()}
        return d
