"""The per-frame glue: frame → perception → tracker → assembly mode → :class:`~tracker.snapshot.Snapshot`.

Plain Python, no HTTP: the web worker, scripts and benchmarks drive it the same way::

    pipeline = AssemblyPipeline(src.parts, src.intrinsics, mode="guidance", task="guidance-demo",
                                initial_poses=src.initial_poses)
    for frame in src:
        snap = pipeline.process(frame)

Per frame: the table plane is found on the first frame with depth (perception's ``detect_table``, tens
of milliseconds) and re-checked every ``table_recheck_s`` seconds on a cheap subsampled grid of the
depth (well under a millisecond); only when that check finds much less of the table on the plane than at
detection (the camera moved) is the full detection run again. Then colour detections of every
coloured part; one step of the multi-object particle filter (with the mode's connection hints); the
mode's update (instruction, connections, verdicts). A stage that fails on a frame is reported in
``Snapshot.errors`` and the rest of the frame still runs. Poses are camera-frame (metres, quaternions
``[x, y, z, w]``).

With ``hands=True`` the hand tracker runs in the perceive stage (:class:`tracker.hands.loop.HandLoop`): its hand
mask is the cube tracker's occluder prior, touching / holding per part is computed after the estimate and shown in
``Snapshot.hands`` ("holding the red cube"), and the touched parts gate the mode's connection decisions
(``AssemblyParams.hand_gate``). The hand step runs in the hand loop's worker thread beside the colour detection and
the cube tracker (``HandLoopConfig.overlap``; by default the tracker's occluder prior is the previous frame's hand
mask predicted to this frame) and is joined before touching / holding.

Parts without a pose are not tracked until they are placed: by a rectangle the user draws
(``tracker.perception.box_tools.pose_from_rect`` + :meth:`~AssemblyPipeline.set_part_pose`), by
:meth:`AssemblyPipeline.auto_place` (automatic first-frame pose initialisation,
`pose_initialization`), or, with ``auto_place=True``, automatically: while some part has no pose,
``auto_place`` is tried on a frame with a table plane at most every ``auto_place_interval_s`` seconds (frame
time); parts it cannot find are reported in ``Snapshot.errors`` (``"auto-place <part>: <reason>"``) until found.

Camera ego-motion (``odometry="default"`` or ``"fastslam"``; ``"off"`` by default): before perception, the odometry
stage (:class:`~tracker.odometry.ego_motion.EgoMotion`: hands, moving parts and foreground masked) estimates the
camera's pose in the world frame (= the first frame's camera frame); the tracker's particles are moved by the
camera's motion (:func:`~tracker.filter.camera_motion.apply_camera_motion`) so that static parts stay put, and the
table plane is propagated instead of re-checked. A frame whose odometry fails keeps the camera-frame prediction
and gets the usual table re-check at once. Poses stay camera-frame; ``Snapshot.camera_pose`` /
``camera_pose_ok`` carry the camera's pose.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from tracker.frame import Frame
from tracker.geometry.camera import Intrinsics
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose
from tracker.snapshot import Snapshot

log = logging.getLogger(__name__)

MODE_NAMES = ("guidance", "guess", "learning")
"""The assembly modes (engineer 5's ``build_mode`` names); ``None`` runs tracking only."""

TABLE_CHECK_STEP = 8
"""Pixel step of the depth grid used to re-check the table plane (every 8th pixel: 4800 points at 640×480)."""
TABLE_CHECK_TOLERANCE = 0.015
"""Metres: a grid point within this distance of the plane counts as lying on it."""
TABLE_CHECK_KEEP = 0.5
"""The plane is kept while the on-plane share of the grid is at least this fraction of the share at detection."""

DEFAULT_TASKS = {"guidance": "guidance-5-cubes", "guess": "guess-structures", "learning": "learning-4-words"}
"""Task used for a mode when none is named (preset ids of ``tracker.assembly``)."""


def _pose_to_dict(pose: Pose) -> dict[str, list[float]]:
    return {"t": [float(x) for x in pose.t], "q": [float(x) for x in pose.q]}


def _json_safe(value: Any) -> Any:
    """Turn numpy scalars/arrays and Poses inside a mode-state dict into JSON-able values."""
    kind = type(value)
    if kind is float:  # the common leaves first (exact types: numpy scalars subclass float and int)
        return value if math.isfinite(value) else None
    if kind is str or kind is int or kind is bool or value is None:
        return value
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    if isinstance(value, np.ndarray):
        return _json_safe(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Pose):
        return _pose_to_dict(value)
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


@dataclass
class PreparedFrame:
    """Work on a frame done before its turn, outside the pipeline's thread (:meth:`AssemblyPipeline.prepare`): the
    colour detections of ``frame`` by ``detector`` with its ranges ``ranges`` (the detector's ``ranges.items()`` as a
    tuple, read before and after detecting), and the thread CPU seconds they took."""

    frame: Frame
    detector: Any
    ranges: tuple
    detections: dict
    cpu_s: float

    def valid_for(self, frame: Frame, detector: Any) -> bool:
        """Whether these detections are ``frame``'s by ``detector`` with its current ranges."""
        return (detector is not None and self.frame is frame and self.detector is detector
                and tuple(detector.ranges.items()) == self.ranges)  # fmt: skip


def resolve_task(task: Any) -> Any:
    """A task object from a preset id or a task-file path; objects (TaskModel, SentenceTask) pass through."""
    if not isinstance(task, str):
        return task
    from pathlib import Path

    from tracker.assembly import load_preset, load_task

    if task.endswith((".yaml", ".yml")) and Path(task).is_file():
        return load_task(task)
    return load_preset(task)


class AssemblyPipeline:
    """Runs perception, the tracker and an assembly mode on each frame and returns a Snapshot.

    * ``parts``: the parts to track; ``intrinsics``: of the colour/depth images.
    * ``mode``: ``"guidance"``, ``"guess"``, ``"learning"`` or ``None`` (tracking only).
    * ``task``: what ``tracker.assembly.build_mode`` accepts (a preset id, a task object or a path);
      ``None`` uses :data:`DEFAULT_TASKS`.
    * ``config``: a ``TrackerConfig`` (or preset name) for the particle filter.
    * ``initial_poses``: camera-frame poses to initialise the tracker with (simulator, objects.json);
      parts without one wait for :meth:`set_part_pose` (a box drawn by the user).
    * ``table_recheck_s``: seconds between table-plane re-detections.
    * ``source_info``: the source's metadata, copied into every snapshot.
    * ``auto_place``: while some part has no pose, find the missing poses automatically (see the module
      docstring) at most every ``auto_place_interval_s`` seconds of frame time.
    * ``word_assignment``: for the learning mode, called with each freshly built mode; a cube → word dict it
      returns replaces the mode's random assignment (the simulator's scripted user builds its row in a fixed
      order: ``tracker.sources.simulator.scripted_words``); ``None`` keeps the mode's own.
    * ``odometry``: ``"off"``, ``"default"`` (dense RGB-D odometry) or ``"fastslam"`` (see the module docstring).
    * ``hands``: run the hand tracker (see the module docstring); ``hand_config``: its
      :class:`~tracker.hands.loop.HandLoopConfig` (None: defaults).
    """

    def __init__(
        self,
        parts: list[PartSpec],
        intrinsics: Intrinsics,
        mode: str | None = "guidance",
        task: Any = None,
        config: Any = None,
        seed: int = 0,
        initial_poses: Mapping[str, Pose] | None = None,
        table_recheck_s: float = 3.0,
        source_info: dict[str, Any] | None = None,
        auto_place: bool = False,
        auto_place_interval_s: float = 2.0,
        word_assignment: Callable[[Any], dict[str, str] | None] | None = None,
        odometry: str = "off",
        hands: bool = False,
        hand_config: Any = None,
    ) -> None:
        if not parts:
            raise ValueError("pipeline: no parts to track")
        names = [p.name for p in parts]
        if len(set(names)) != len(names):
            raise ValueError(f"pipeline: part names must be unique, got {names}")
        if mode is not None and mode not in MODE_NAMES:
            raise ValueError(f"pipeline: unknown mode {mode!r}; choose one of {', '.join(MODE_NAMES)}")
        self.parts = list(parts)
        self.intrinsics = intrinsics
        self.config = config
        self.seed = int(seed)
        self.table_recheck_s = float(table_recheck_s)
        self.source_info = dict(source_info or {})
        self.auto_place_enabled = bool(auto_place)
        self.auto_place_interval_s = float(auto_place_interval_s)
        self.word_assignment = word_assignment
        self._auto_place_time: float | None = None  # frame time of the last automatic attempt
        self._auto_place_errors: dict[str, str] = {}  # part -> why the last automatic attempt did not find it
        self.carried: list[str] = []  # parts the tracker holds hidden in a hand (TrackerState.carried)
        self._initial_poses = {k: v for k, v in (initial_poses or {}).items() if k in names}
        self.poses: dict[str, Pose] = dict(self._initial_poses)
        self.table = None
        self._table_time: float | None = None
        self._table_share = 0.0  # share of the check grid on the plane when it was detected
        self._table_rays: tuple[tuple[int, int], np.ndarray] | None = None  # (depth shape, normal · grid rays)
        self._fps = 0.0
        self._last_wall: float | None = None
        self._setup_errors: list[str] = []
        self.detector = self._make_detector()
        self.ego = self._make_ego_motion(odometry)
        self._tracked_names: list[str] = []
        self._corners: dict[str, tuple[PartSpec, np.ndarray]] = {}  # name -> (part, body-frame corners) for _boxes
        self._hand_config = hand_config
        self.hands = self._make_hands() if hands else None
        self._hands_joined = True  # the hand step of the current frame has been waited for (or none was started)
        self._touched: set[str] | None = None  # parts the hands touched at the last frame, taken before the hand step
        self.tracker = None
        self._initialize_tracker()
        self.mode_name: str | None = None
        self.task: Any = None
        self.mode = None
        self.set_mode(mode, task)

    # ----------------------------------------------------------------- construction of the stages
    def _make_detector(self):
        try:
            from tracker.perception.color_detection import ColorDetector
        except ImportError as exc:
            self._setup_errors.append(f"colour detection unavailable: {exc}")
            return None
        coloured = [p for p in self.parts if p.color is not None]
        return ColorDetector.from_parts(coloured) if coloured else None

    def _make_ego_motion(self, odometry: str):
        """The camera odometry stage (None when ``odometry`` is ``"off"``)."""
        from tracker.odometry.ego_motion import MODES, EgoMotion

        if odometry not in MODES:
            raise ValueError(f"pipeline: odometry must be one of {', '.join(MODES)}, got {odometry!r}")
        return None if odometry == "off" else EgoMotion(odometry, self.intrinsics, self.parts, seed=self.seed)

    def _make_hands(self):
        """The hand tracker with its contact monitor (:class:`tracker.hands.loop.HandLoop`), None if unavailable."""
        try:
            from tracker.hands.loop import HandLoop
        except ImportError as exc:
            self._setup_errors.append(f"hand tracking unavailable: {exc}")
            return None
        return HandLoop(self.parts, self.intrinsics, self._hand_config)

    def _make_tracker(self):
        """The particle filter for the parts that have a pose so far (``None`` until one has)."""
        tracked = [p for p in self.parts if p.name in self.poses]
        self._tracked_names = [p.name for p in tracked]
        if not tracked:
            return None
        try:
            from tracker.filter.particle_filter import MultiObjectTracker
        except ImportError as exc:
            self._setup_errors.append(f"depth tracker unavailable: {exc}")
            return None
        config = self.config
        if isinstance(config, str):
            from tracker.filter.tracker_config import TrackerConfig

            is_file = config.endswith((".yaml", ".yml", ".toml"))
            config = TrackerConfig.load(config) if is_file else TrackerConfig.preset(config)
        return MultiObjectTracker(tracked, self.intrinsics, config, seed=self.seed)

    def _initialize_tracker(self) -> None:
        """(Re)start the filter at the current poses; rebuilt when a part got its first pose."""
        if self.tracker is None or self._tracked_names != [p.name for p in self.parts if p.name in self.poses]:
            self.tracker = self._make_tracker()
        if self.tracker is not None:
            self.tracker.initialize({n: self.poses[n] for n in self._tracked_names})

    def set_mode(self, mode: str | None, task: Any = None) -> None:
        """Switch the assembly mode (``None``: tracking only); ``task`` as for the constructor."""
        if mode is not None and mode not in MODE_NAMES:
            raise ValueError(f"unknown mode {mode!r}; choose one of {', '.join(MODE_NAMES)}")
        if mode is None:
            self.mode_name, self.task, self.mode = None, None, None
            return
        if task is None:
            task = DEFAULT_TASKS[mode]
        from tracker.assembly import SentenceTask, build_mode

        if isinstance(task, SentenceTask):
            if mode != "learning":
                raise ValueError("a sentence task needs the learning mode")
            built = build_mode(self._sentence_task_model(task), mode, self.parts, self.seed, sentence=task)
        else:
            built = build_mode(resolve_task(task), mode, self.parts, self.seed)
        if mode == "learning" and self.word_assignment is not None:
            assignment = self.word_assignment(built)
            if assignment:
                built = build_mode(built.task, "learning", self.parts, self.seed, sentence=built.sentence,
                                   assignment=assignment)
        self.mode_name, self.task, self.mode = mode, task, built
        if self.tracker is not None:
            self.tracker.set_connection_hints([])

    def _sentence_task_model(self, sentence):
        """A learning task around one sentence (e.g. a teacher's) using every part of this pipeline as a cube."""
        from tracker.assembly import TaskModel

        parts = [
            {"name": p.name, "shape": "box", "size": list(p.box), "colour": None if p.color is None else list(p.color)}
            for p in self.parts
            if p.box is not None
        ]
        return TaskModel(
            id=f"sentence-{sentence.id or 'custom'}", mode="learning", units="m", parts=parts, sentences=[sentence]
        )

    # ----------------------------------------------------------------- user interaction
    def set_part_pose(self, name: str, pose: Pose) -> None:
        """(Re-)start tracking ``name`` at a camera-frame pose (e.g. from a box drawn on the image)."""
        if name not in {p.name for p in self.parts}:
            raise ValueError(f"unknown part {name!r}; parts are {', '.join(p.name for p in self.parts)}")
        self.poses[name] = pose
        self._initialize_tracker()

    def unplaced(self) -> list[str]:
        """Names of the parts that have no pose yet (not tracked), in part order."""
        return [p.name for p in self.parts if p.name not in self.poses]

    def auto_place(
        self, frame: Frame, names: list[str] | None = None, detections: Mapping | None = None
    ) -> dict[str, dict[str, Any]]:
        """Find the poses of parts resting on the table in ``frame`` and start tracking them there.

        ``names``: the parts to place (default: every part without a pose; a tracked part that is named is
        placed again). Uses the current table plane (detected from the frame when there is none yet), the
        colour detections (``detections`` or the pipeline's detector on the frame) and leaves the image
        regions of the other tracked parts out (``known``). Returns per part ``{"t": [3] m, "q": [x, y, z, w],
        "residual_mm": float, "method": str}`` (camera frame) or ``{"error": message}`` for a part that was
        not found; the found ones are set like :meth:`set_part_pose` (the tracker is re-initialised). Raises
        ValueError only for an unknown part name.
        """
        from tracker.perception.pose_initialization import initialize_poses

        if names is None:
            names = self.unplaced()
        names = list(dict.fromkeys(names))
        for n in names:
            self.part(n)  # unknown name: ValueError
        if not names:
            return {}
        out: dict[str, dict[str, Any]] = {}
        table = self.table
        if frame.depth is None:
            return {n: {"error": f"frame {frame.index} has no depth image"} for n in names}
        if table is None:
            from tracker.perception.table_plane import detect_table

            try:
                table = self.table = detect_table(frame.depth, frame.intrinsics)
            except ValueError as exc:
                return {n: {"error": f"no table plane in frame {frame.index}: {exc}"} for n in names}
            self._table_time, self._table_rays = frame.timestamp, None
            self._table_share = self._on_table_share(frame.depth, frame.intrinsics)
        if detections is None and self.detector is not None:
            try:
                detections = self.detector.detect(frame.color)
            except Exception as exc:  # noqa: BLE001 - initialize_poses detects the colours itself
                log.warning("auto-place: colour detection failed: %s", exc)
                detections = None
        if detections is not None:  # parts the pipeline's detector does not know are detected by initialize_poses
            coloured = {p.name for p in self.parts if p.color is not None}
            if not all(n in detections for n in names if n in coloured):
                detections = None
        known = {n: (self.part(n), pose) for n, pose in self.poses.items() if n not in names}
        parts = [self.part(n) for n in names]
        try:
            found = initialize_poses(frame, parts, table=table, detections=detections, known=known)
        except ValueError:
            # one part spoils the joint call: place them one by one, each leaving out the ones found before
            found = {}
            for p in parts:
                try:
                    found.update(initialize_poses(frame, [p], table=table, detections=detections, known=known))
                except ValueError as exc:
                    out[p.name] = {"error": str(exc)}
                    continue
                known[p.name] = (p, found[p.name].pose)
        except Exception as exc:  # noqa: BLE001 - an unexpected failure is reported, never raised
            log.exception("auto-place failed on frame %s", frame.index)
            return {n: {"error": f"{type(exc).__name__}: {exc}"} for n in names}
        for n in names:
            if n in found:
                r = found[n]
                self.poses[n] = r.pose
                out[n] = {**_pose_to_dict(r.pose), "residual_mm": float(r.residual_mm), "method": r.method}
        if found:
            self._initialize_tracker()
        return {n: out[n] for n in names}

    def _auto_place_step(self, frame: Frame, detections: Mapping | None, errors: list[str]) -> None:
        """Automatic mode: try :meth:`auto_place` on the missing parts when due; report who is still missing."""
        missing = self.unplaced()
        if not missing:
            self._auto_place_errors.clear()
            return
        last = self._auto_place_time
        due = last is None or abs(frame.timestamp - last) >= self.auto_place_interval_s
        if due and self.table is not None and frame.depth is not None:
            self._auto_place_time = frame.timestamp
            try:
                results = self.auto_place(frame, missing, detections=detections or None)
            except Exception as exc:  # noqa: BLE001 - reported, tried again later
                results = {n: {"error": f"{type(exc).__name__}: {exc}"} for n in missing}
            self._auto_place_errors = {n: r["error"] for n, r in results.items() if "error" in r}
        missing = self.unplaced()
        waiting = [n for n in missing if n not in self._auto_place_errors]
        if waiting:
            errors.append(f"auto-place: waiting for a frame with depth and a table to find {', '.join(waiting)}")
        errors.extend(f"auto-place {n}: {self._auto_place_errors[n]}" for n in missing if n in self._auto_place_errors)

    def part(self, name: str) -> PartSpec:
        for p in self.parts:
            if p.name == name:
                return p
        raise ValueError(f"unknown part {name!r}; parts are {', '.join(p.name for p in self.parts)}")

    def close(self, keep_hand_process: bool = False) -> None:
        """End the hand step's thread or process (:meth:`HandLoop.close`; with ``keep_hand_process`` a healthy hand
        process is kept for the next pipeline of the same parts). The pipeline still works: a later frame starts the
        hand step again."""
        if self.hands is not None:
            self.hands.close(keep_process=keep_hand_process)

    def reset(self) -> None:
        """Back to the initial poses, a fresh mode and a table to be found again."""
        self.poses = dict(self._initial_poses)
        self.table, self._table_time, self._table_rays = None, None, None
        self._fps, self._last_wall = 0.0, None
        self._auto_place_time, self._auto_place_errors, self.carried = None, {}, []
        if self.hands is not None:
            self.hands.close(keep_process=True)  # the same parts: the new loop takes the hand process
            self.hands = self._make_hands()
        self.tracker = None
        if self.ego is not None:
            self.ego.reset()
        self._initialize_tracker()
        self.set_mode(self.mode_name, self.task)

    # ----------------------------------------------------------------- the per-frame cycle
    def _on_table_share(self, depth: np.ndarray, intrinsics: Intrinsics) -> float:
        """Share of a subsampled depth grid (every :data:`TABLE_CHECK_STEP` th pixel) lying on ``self.table``."""
        k = TABLE_CHECK_STEP
        if self._table_rays is None or self._table_rays[0] != depth.shape:
            h, w = depth.shape
            v, u = np.mgrid[0:h:k, 0:w:k].astype(np.float32)
            n = np.asarray(self.table.normal, np.float32)
            dots = n[0] * (u - intrinsics.cx) / intrinsics.fx + n[1] * (v - intrinsics.cy) / intrinsics.fy + n[2]
            self._table_rays = (depth.shape, dots)
        z = depth[::k, ::k]
        with np.errstate(invalid="ignore"):
            on = np.abs(z * self._table_rays[1] + np.float32(self.table.offset)) < TABLE_CHECK_TOLERANCE
        return float(np.count_nonzero(on)) / max(1, on.size)

    def _update_table(self, frame: Frame, errors: list[str]) -> None:
        if self.ego is not None and self.ego.has_table:
            if self.ego.moved:  # odometry on and the camera moved: the plane is propagated (_follow_camera)
                return
            if not self.ego.ok:
                self._table_time = None  # the odometry failed: re-check the plane now
            # else no camera motion applied (idle, dead band): the plane is checked as with odometry off
        if frame.depth is None:
            return
        due = self._table_time is None or abs(frame.timestamp - self._table_time) >= self.table_recheck_s
        if not due:
            return
        self._table_time = frame.timestamp
        if self.table is not None:
            share = self._on_table_share(frame.depth, frame.intrinsics)
            if share >= TABLE_CHECK_KEEP * self._table_share:
                return  # still the same plane: no full detection
            log.info("table plane re-detected: %.0f %% of the grid on it, %.0f %% at detection",
                     100 * share, 100 * self._table_share)  # fmt: skip
        from tracker.perception.table_plane import detect_table

        try:
            self.table = detect_table(frame.depth, frame.intrinsics)
        except ValueError as exc:  # TableNotFoundError is a ValueError
            errors.append(f"table: {exc}")
            return
        self._table_rays = None
        self._table_share = self._on_table_share(frame.depth, frame.intrinsics)
        if self.ego is not None:
            self.ego.anchor_table(self.table)

    def _boxes(self) -> dict[str, list[float]]:
        """Per box part with a pose: the pixel box ``[u0, v0, u1, v1]`` of its projected corners (none when a corner
        is within 1 mm of the camera plane)."""
        out: dict[str, list[float]] = {}
        for part in self.parts:
            pose = self.poses.get(part.name)
            if pose is None or part.box is None:
                continue
            corners = self._corners.get(part.name)
            if corners is None or corners[0] is not part:  # body-frame corners, made once per (frozen) part
                corners = self._corners[part.name] = (part, part.vertices())
            pts = pose.transform_points(corners[1])
            if np.any(pts[:, 2] <= 1e-3):
                continue
            uv = self.intrinsics.project(pts)
            lo, hi = uv.min(axis=0).tolist(), uv.max(axis=0).tolist()
            out[part.name] = [lo[0], lo[1], hi[0], hi[1]]
        return out

    def prepare(self, frame: Frame) -> PreparedFrame | None:
        """The colour detections of ``frame``, made ahead of its turn in another thread (the server's frame reader
        runs this on the next frame while this pipeline processes the current one, so the detection leaves the
        pipeline's thread): :meth:`process` given the result uses them while the detector and its ranges are still
        those they were made with, and detects again otherwise, so a snapshot is the same either way. None without a
        detector, or if detecting fails (:meth:`process` then detects and reports the error). With hands on it also
        copies the frame into the hand process's shared memory (:meth:`HandLoop.stage`; the step then sends it without
        copying). Reads only the detector, the hand loop and the frame, so it may run beside :meth:`process` of an
        earlier frame."""
        hands = self.hands
        if hands is not None:  # the frame's copy for the hand process, off the pipeline thread (HandLoop.stage)
            try:
                hands.stage(frame.color, frame.depth)
            except Exception:  # noqa: BLE001 - the step copies the frame itself
                pass
        detector = self.detector
        if detector is None:
            return None
        c0 = time.thread_time()
        try:
            ranges = tuple(detector.ranges.items())
            detections = detector.detect(frame.color)
            if tuple(detector.ranges.items()) != ranges:  # changed meanwhile: process() detects
                return None
        except Exception:  # noqa: BLE001 - process() detects again and reports the error
            return None
        return PreparedFrame(frame, detector, ranges, detections, time.thread_time() - c0)

    def process(self, frame: Frame, wall_time: float | None = None, prepared: PreparedFrame | None = None) -> Snapshot:
        """Run every stage on ``frame``; ``wall_time`` is its capture time, ``time.time()`` (default: now);
        ``prepared``: :meth:`prepare` of this frame, if it was run (its detections are used when still valid).

        perceive (table plane, colour detections, automatic placement) → estimate (the tracker) → monitor (the
        assembly mode) → snapshot. A stage that fails is reported in ``Snapshot.errors``; the frame goes on."""
        wall = time.time() if wall_time is None else float(wall_time)
        errors: list[str] = list(self._setup_errors)
        timings: dict[str, float] = {}
        if self.ego is not None:
            self._follow_camera(frame, errors, timings)
        detections = self._perceive(frame, errors, timings, prepared)
        particles = self._estimate(frame, detections, errors, timings)
        self._hand_contacts(frame, errors, timings)
        mode_state = self._monitor(frame, errors, timings)
        self._count_fps()
        return self._snapshot(frame, wall, detections, particles, mode_state, errors, timings)

    def _follow_camera(self, frame: Frame, errors: list[str], timings: dict[str, float]) -> None:
        """Odometry on: the camera's pose; the tracker's state moved by the camera's motion; the table propagated
        (a plane found since the last frame is anchored in the world frame first)."""
        from tracker.filter.camera_motion import apply_camera_motion

        t0 = time.perf_counter()
        try:
            if self.table is not None and not self.ego.has_table:
                self.ego.anchor_table(self.table)
            ego = self.ego.step(frame, self.table, self.poses, self.carried, self._hand_boxes(frame))
            if not ego.ok:
                errors.append(f"odometry: {ego.message}")
            if ego.camera_motion is not None and self.tracker is not None:
                apply_camera_motion(self.tracker, ego.camera_motion)
                self.poses.update(self.tracker.estimates)
            if self.ego.moved and self.ego.has_table:
                self.table = self.ego.table_in_camera()
                self._table_rays = None
        except Exception as exc:  # noqa: BLE001 - a failing stage is reported, the frame goes on
            log.exception("odometry failed on frame %s", frame.index)
            errors.append(f"odometry: {type(exc).__name__}: {exc}")
        timings["odometry"] = time.perf_counter() - t0

    def _hand_boxes(self, frame: Frame) -> list:
        """Pixel boxes of the hands for the odometry's mask: those in ``frame.meta["hand_boxes"]`` and, with hands
        on, the hand tracker's latest boxes (its last step's: a frame behind when it runs beside the tracker)."""
        from tracker.odometry.ego_motion import frame_hand_boxes

        tracked = [] if self.hands is None else [e.box for e in self.hands.estimates]
        return frame_hand_boxes(frame, tracked)

    def _perceive(self, frame: Frame, errors: list[str], timings: dict[str, float],
                  prepared: PreparedFrame | None = None) -> dict:  # fmt: skip
        """Table plane (found, re-checked), colour detections (``prepared``'s when made for this frame by the current
        detector with its current ranges; their thread CPU time goes to ``timings["detection_ahead"]``) and, when on,
        automatic placement of missing parts."""
        t0 = time.perf_counter()
        try:
            self._update_table(frame, errors)
        except Exception as exc:  # noqa: BLE001 - a failing stage is reported, the frame goes on
            errors.append(f"table: {type(exc).__name__}: {exc}")
        timings["table"] = time.perf_counter() - t0
        if self.hands is not None:
            self._start_hands(frame, errors, timings)

        t0 = time.perf_counter()
        detections: dict = {}
        if prepared is not None and prepared.valid_for(frame, self.detector):
            detections = prepared.detections
            timings["detection_ahead"] = prepared.cpu_s
        elif self.detector is not None:
            try:
                detections = self.detector.detect(frame.color)
            except Exception as exc:  # noqa: BLE001
                errors.append(f"colour detection: {type(exc).__name__}: {exc}")
        timings["detection"] = time.perf_counter() - t0

        if self.auto_place_enabled:
            t0 = time.perf_counter()
            try:
                self._auto_place_step(frame, detections, errors)
            except Exception as exc:  # noqa: BLE001 - a failing stage is reported, the frame goes on
                log.exception("automatic placement failed on frame %s", frame.index)
                errors.append(f"auto-place: {type(exc).__name__}: {exc}")
            timings["auto_place"] = time.perf_counter() - t0
        return detections

    def _start_hands(self, frame: Frame, errors: list[str], timings: dict[str, float]) -> None:
        """Start one hand-tracker step (the table plane and the parts' last poses exclude pixels that cannot be a
        hand) in the hand loop's worker thread (:meth:`HandLoop.start`); the parts the hands touched at the last
        frame are taken first, for the cube tracker, which may run while the step does."""
        from tracker.filter.frame_context import table_normal_offset

        self._hands_joined = False
        self._touched = self.hands.touched_parts()
        try:
            self.hands.start(frame.color, frame.depth, table_normal_offset(self.table), self.poses)
        except Exception as exc:  # noqa: BLE001 - a failing stage is reported, the frame goes on
            self._hands_joined = True
            log.exception("hand tracking failed on frame %s", frame.index)
            errors.append(f"hands: {type(exc).__name__}: {exc}")

    def _join_hands(self, frame: Frame, errors: list[str], timings: dict[str, float]) -> None:
        """Wait for the hand step started by :meth:`_start_hands` (once per frame); its wall and thread CPU time go to
        ``timings["hands"]`` / ``["hands_cpu"]``, the time this thread waited for it to ``["hands_wait"]``."""
        if self._hands_joined:
            return
        self._hands_joined = True
        t0 = time.perf_counter()
        try:
            self.hands.wait()
        except Exception as exc:  # noqa: BLE001 - a failing stage is reported, the frame goes on
            log.exception("hand tracking failed on frame %s", frame.index)
            errors.append(f"hands: {type(exc).__name__}: {exc}")
        timings["hands_wait"] = time.perf_counter() - t0
        timings["hands"], timings["hands_cpu"] = self.hands.step_seconds

    def _hand_contacts(self, frame: Frame, errors: list[str], timings: dict[str, float]) -> None:
        """Touching / holding per hand and part at the new estimated poses (for the panel and the connection gate)."""
        if self.hands is None:
            return
        self._join_hands(frame, errors, timings)
        t0 = time.perf_counter()
        try:
            self.hands.update_contacts(self.poses, frame.depth)
        except Exception as exc:  # noqa: BLE001
            log.exception("hand contacts failed on frame %s", frame.index)
            errors.append(f"hand contacts: {type(exc).__name__}: {exc}")
        timings["hand_contacts"] = time.perf_counter() - t0

    def _hands_for_tracker(self, frame: Frame, errors: list[str],
                           timings: dict[str, float]) -> tuple[np.ndarray | None, set[str] | None]:  # fmt: skip
        """The hand occluder mask and the touched parts for the cube tracker's step (None, None with hands off). With
        ``overlap`` "lagged" the mask is the last frame's predicted to this one and the hand step keeps running;
        else the step is joined first and the touched parts are read after it (as without the worker)."""
        if self.hands is None:
            return None, None
        if self.hands.config.overlap == "lagged":
            return self.hands.tracker_occluders(), self._touched
        self._join_hands(frame, errors, timings)
        return self.hands.tracker_occluders(), self.hands.touched_parts()

    def _estimate(self, frame: Frame, detections: dict, errors: list[str],
                  timings: dict[str, float]) -> dict[str, np.ndarray]:
        """One tracker step with the mode's connection hints; updates ``self.poses``; returns the particle clouds."""
        t0, c0 = time.perf_counter(), time.thread_time()
        particles: dict[str, np.ndarray] = {}
        if self.tracker is not None and self.poses:
            try:
                if self.mode is not None:
                    tracked = set(self._tracked_names)
                    hints = [h for h in self.mode.connection_hints() if {h.first, h.second} <= tracked]
                    self.tracker.set_connection_hints(hints)
                occluders, touched = self._hands_for_tracker(frame, errors, timings)
                fused = self.ego is not None and self.ego.fused is not None
                if fused:
                    from tracker.filter.camera_motion import hand_hidden_parts_to_the_odometry

                    hand_hidden_parts_to_the_odometry(self.tracker, self.ego)
                state = self.tracker.step(frame, detections or None, self.table, occluders=occluders, touched=touched)
                if fused:  # odometry fused: the parts check the camera; the hidden parts follow its correction
                    from tracker.filter.camera_motion import follow_correction

                    corners = {n: self.tracker.corners[i] for i, n in enumerate(self.tracker.names)}
                    correction = self.ego.observe(self.tracker.landmark_poses, corners)
                    if correction is not None:
                        follow_correction(self.tracker, correction, state.poses)
                self.poses.update(state.poses)
                self.carried = [str(n) for n in (getattr(state, "carried", None) or [])]
                particles = {k: np.asarray(v, np.float32) for k, v in state.particles.items()}
                for k, v in (getattr(state, "timings", None) or {}).items():
                    timings[f"tracker.{k}"] = float(v) / 1000.0  # the tracker reports milliseconds
            except Exception as exc:  # noqa: BLE001
                log.exception("tracker failed on frame %s", frame.index)
                errors.append(f"tracker: {type(exc).__name__}: {exc}")
        if self.tracker is None:
            self.carried = []
        timings["tracker"] = time.perf_counter() - t0
        timings["tracker_cpu"] = time.thread_time() - c0  # this thread's CPU time (wall time minus waiting for a core)
        return particles

    def _monitor(self, frame: Frame, errors: list[str], timings: dict[str, float]) -> dict[str, Any]:
        """The assembly mode's update on the current poses (needs the table plane); its state as a JSON-able dict."""
        t0 = time.perf_counter()
        mode_state: dict[str, Any] = {}
        if self.mode is not None:
            self.mode.set_hand_contacts(None if self.hands is None else self.hands.touched_parts())
            t2c = self.table.table_to_camera() if self.table is not None else None
            if t2c is None:
                errors.append("mode: waiting for the table plane")
            else:
                try:
                    mode_state = _json_safe(self.mode.update(frame.timestamp, dict(self.poses), t2c).to_dict())
                except Exception as exc:  # noqa: BLE001
                    log.exception("mode failed on frame %s", frame.index)
                    errors.append(f"mode: {type(exc).__name__}: {exc}")
        timings["mode"] = time.perf_counter() - t0
        return mode_state

    def _count_fps(self) -> None:
        """Processed-frame rate from the ends of processing (capture times may be uneven)."""
        done = time.time()
        if self._last_wall is not None:
            dt = done - self._last_wall
            if dt > 0:
                inst = 1.0 / dt
                self._fps = inst if self._fps == 0.0 else 0.9 * self._fps + 0.1 * inst
        self._last_wall = done

    def _snapshot(self, frame: Frame, wall: float, detections: dict, particles: dict[str, np.ndarray],
                  mode_state: dict[str, Any], errors: list[str], timings: dict[str, float]) -> Snapshot:
        table = None
        if self.table is not None:
            table = {
                "normal": [float(x) for x in self.table.normal],
                "offset": float(self.table.offset),
                "table_to_camera": _pose_to_dict(self.table.table_to_camera()),
            }
        det_json = {}
        for name, d in detections.items():
            det_json[name] = {
                "center": None if d.center is None else [float(d.center[0]), float(d.center[1])],
                "bbox": None if d.bbox is None else [float(v) for v in d.bbox],
                "score": float(d.score),
                "area": float(d.area),
            }
        instruction = str(mode_state.get("instruction", "") or "")
        connections = mode_state.get("connections", [])
        if not isinstance(connections, list):
            connections = []
        return Snapshot(
            frame_index=frame.index,
            time=frame.timestamp,
            wall_time=wall,
            poses=dict(self.poses),
            particles=particles,
            boxes=self._boxes(),
            detections=det_json,
            connections=connections,
            mode=self.mode_name,
            mode_state=mode_state,
            instruction=instruction,
            table=table,
            fps=self._fps,
            timings=timings,
            source=self.source_info,
            errors=errors,
            carried=list(self.carried),
            camera_pose=None if self.ego is None else self.ego.pose,
            camera_pose_ok=True if self.ego is None else bool(self.ego.ok),
            hands=[] if self.hands is None else self.hands.hands(),
            image_size=(frame.intrinsics.width, frame.intrinsics.height),
        )
