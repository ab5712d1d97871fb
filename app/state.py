"""What the endpoints share: :class:`AppState` (settings, storage, auth, worker, scene, current selection).

The pipeline worker thread runs the tracker; endpoints only read its latest snapshot or queue a command
for it (:meth:`AppState.on_worker`), so HTTP handling never waits for a frame to be processed.
"""

from __future__ import annotations

import functools
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from app import api_models as m
from app.auth import TeacherAuth
from app.limits import Limits
from app.settings import Settings
from app.storage import StorageError, open_storage
from app.validation import check_preset_id, teacher_task_id
from app.worker import PipelineWorker
from tracker.assembly import SentenceTask
from tracker.geometry.parts import PartSpec
from tracker.pipeline import AssemblyPipeline
from tracker.sources.base import FrameSource

log = logging.getLogger(__name__)

WEB_DIR = Path(__file__).resolve().parents[1] / "web"
DEFAULT_CAMERA_PARTS = ("red", "green", "blue", "yellow", "orange")
"""Parts assumed for a live camera (no objects.json): the five seed cubes."""
COMMAND_TIMEOUT_S = 20.0


def version() -> str:
    try:
        return metadata.version("assembly-agent")
    except metadata.PackageNotFoundError:
        return "0.0.0"


def open_source_spec(spec: str, realtime: bool = False, seed: int = 0) -> FrameSource:
    """Open ``sim:<scenario>``, ``recording:<dir>`` or ``camera:<n>`` through the sources registry.

    The server opens simulated and recorded sources unpaced (``realtime=False``): the worker paces them
    itself at their frame rate and skips frames that became stale (see :class:`app.worker.PipelineWorker`). Its
    frame reader produces each frame in a thread of its own just in time, so a recording does not decode ahead
    (``prefetch=0``: it would decode frames the reader then skips).
    """
    from tracker.sources.registry import open_source

    return open_source(spec, realtime=realtime, seed=seed, loop=False, prefetch=0)


def available_sources() -> list[m.SourceInfo]:
    out: list[m.SourceInfo] = []
    try:
        from tracker.sources.simulator import list_scenarios

        for sc in list_scenarios():
            name = sc if isinstance(sc, str) else getattr(sc, "name", str(sc))
            desc = "" if isinstance(sc, str) else str(getattr(sc, "description", ""))
            out.append(m.SourceInfo(spec=f"sim:{name}", kind="sim", description=desc))
    except ImportError:
        pass
    out.append(m.SourceInfo(spec="camera:0", kind="camera", description="OpenCV capture device 0 (colour only)"))
    return out


@dataclass
class Calibration:
    """A part's colour range learnt from a drawn box (``frame_index``: the frame it was learnt on)."""

    part: str
    range: Any
    frame_index: int | None = None


class AppState:
    """Everything the endpoints share: settings, storage, auth, worker, scene and the current selection."""

    def __init__(self, settings: Settings, open_source: Callable[[str], FrameSource] | None = None) -> None:
        self.settings = settings
        self.storage = open_storage(
            settings.database_target(), on_damaged=settings.on_damaged_database, wait_s=settings.database_wait_s
        )
        self.auth = TeacherAuth(self.storage, settings.teacher_password)
        self.source_spec = settings.source_spec()
        self.mode = settings.mode
        self.task = settings.task
        self._preset_ids: list[str] | None = None
        self.limits = Limits(settings)
        if self.task is not None:
            self.resolve_task(self.mode, self.task)  # fail early on a bad --task
        self._open = open_source or self._open_spec
        self._process_source: tuple[str, Any] | None = None  # (spec, ProcessSource) kept across reopenings
        self.worker = PipelineWorker(
            self._open_current,
            self._make_pipeline,
            max_fps=settings.max_fps,
            loop=settings.loop,
            realtime=settings.realtime,
            realtime_ahead=settings.realtime_ahead,
        )
        self.scene = None
        self.scene_updater = None
        self.session_id: int | None = None
        self.boxes: list[m.BoxResponse] = []
        self.user_poses: dict[str, Any] = {}  # parts placed by drawn boxes: kept when a source loops or reconnects
        self.calibrations: list[Calibration] = []  # colour ranges learnt from boxes: kept like user_poses
        from app.identical_parts import IdenticalParts

        self.identical = IdenticalParts()  # same-colour parts told apart in the image (Algorithm 2)
        self.worker.frame_hooks.append(self.identical.on_frame)
        from app.results import ResultsRecorder

        self.results = ResultsRecorder(self.storage)  # learner results, written in batches off the frame loop
        self.worker.frame_hooks.append(self.results.on_frame)
        self.round = 0  # pipelines built so far: each opening of the source (a loop, a reset, a switch) is a round
        self._session_frames0 = 0
        self._lock = threading.Lock()

    # -------------------------------------------------------------- source and pipeline
    def _open_current(self) -> FrameSource:
        # A live camera keeps producing while the pipeline is busy: read it continuously and process the
        # newest frame. Simulated and recorded frames are produced on demand, so none is rendered in vain.
        self.worker.drop_stale = self.source_spec.startswith("camera:")
        return self._open(self.source_spec)

    def _open_spec(self, spec: str) -> FrameSource:
        """The registry's source; the simulator renders in a child process that lives until the spec changes."""
        if not (self.settings.source_process and spec.startswith("sim:")):
            self._close_process_source()
            return open_source_spec(spec, False, self.settings.seed)
        from app.source_process import ProcessSource, SharedView, open_registry_source

        cached = self._process_source
        if cached is None or cached[0] != spec or not cached[1].alive:
            self._close_process_source()
            self._process_source = (spec, ProcessSource(open_registry_source, spec, self.settings.seed))
        return SharedView(self._process_source[1])

    def _close_process_source(self) -> None:
        if self._process_source is not None:
            proc, self._process_source = self._process_source[1], None
            proc.close()

    def preset_ids(self) -> list[str]:
        """The ids of the task presets (read once: presets ship with the program)."""
        if self._preset_ids is None:
            from tracker.assembly import list_presets

            self._preset_ids = [p["id"] for p in list_presets()]
        return self._preset_ids

    def hand_config(self) -> Any:
        """The hand loop's configuration from the settings (``hands_worker``: child process or thread)."""
        from tracker.hands.loop import HandLoopConfig

        return HandLoopConfig(worker=self.settings.hands_worker)

    def resolve_task(self, mode: str, ref: str | None) -> Any:
        """The task object for a reference: a preset id, or ``teacher:<n>`` (a stored sentence task).

        Only known preset ids and bounded teacher ids are accepted (:mod:`app.validation`); ValueError otherwise."""
        if ref is None or mode == "none":
            return None
        task_id = teacher_task_id(ref)
        if task_id is not None:
            rec = self.storage.get_task(task_id)
            if rec is None:
                raise ValueError(f"task {ref!r}: no teacher task with id {task_id}")
            if mode != "learning":
                raise ValueError(f"task {ref!r} is a sentence task: select the learning mode for it")
            return SentenceTask(**rec["data"])
        from tracker.assembly import load_preset

        task = load_preset(check_preset_id(ref, self.preset_ids()))
        if task.mode != mode:
            raise ValueError(f"task {ref!r} is a {task.mode} task, not a {mode} task")
        return task

    def task_for_round(self, mode: str, task: Any) -> Any:
        """The task of this round: a learning task with several sentences gets one of them per round, in turn
        (starting from a seeded draw), so every round of a looping source asks for a new sentence."""
        if mode != "learning" or isinstance(task, SentenceTask):
            return task
        if task is None:
            from tracker.assembly import load_preset
            from tracker.pipeline import DEFAULT_TASKS

            task = load_preset(DEFAULT_TASKS["learning"])
        sentences = list(getattr(task, "sentences", None) or [])
        if len(sentences) < 2 or not hasattr(task, "model_copy"):
            return task
        first = int(np.random.default_rng(self.settings.seed).integers(len(sentences)))
        pick = sentences[(first + max(0, self.round - 1)) % len(sentences)]
        return task.model_copy(update={"sentences": [pick]})

    def _make_pipeline(self, src: FrameSource) -> AssemblyPipeline:
        self.round += 1
        parts = getattr(src, "parts", None) or [PartSpec.cube(c, c) for c in DEFAULT_CAMERA_PARTS]
        poses = {**(getattr(src, "initial_poses", None) or {}), **self.user_poses}
        config = self.settings.tracker_config
        # the server's default N (settings.SERVER_PARTICLES) applies to the default preset; a named preset or
        # config file keeps its own N unless --particles / ASSEMBLY_AGENT_N_PARTICLES is given as well
        explicit = "n_particles" in self.settings.model_fields_set
        if self.settings.n_particles is not None and (explicit or not config):
            from tracker.filter.tracker_config import TrackerConfig

            base = (
                TrackerConfig.preset(config or "default")
                if not (config or "").endswith((".yaml", ".yml", ".toml"))
                else TrackerConfig.load(config)
            )
            config = base.with_overrides(n_particles=self.settings.n_particles)

        metadata = safe_metadata(src)
        word_assignment = None
        if metadata.get("scenario"):  # a simulated session (live or recorded): follow its scripted user's row
            from tracker.sources.simulator.scripted_words import scripted_row_assignment

            word_assignment = functools.partial(scripted_row_assignment, metadata["scenario"])

        def build(mode: str, task: str | None) -> AssemblyPipeline:
            return AssemblyPipeline(
                list(parts),
                src.intrinsics,
                mode=None if mode == "none" else mode,
                task=self.task_for_round(mode, self.resolve_task(mode, task)),
                config=config,
                seed=self.settings.seed,
                initial_poses=poses,
                table_recheck_s=self.settings.table_recheck_s,
                source_info={"spec": self.source_spec, "round": self.round, **metadata},
                auto_place=self.settings.auto_place,
                auto_place_interval_s=self.settings.auto_place_interval_s,
                word_assignment=word_assignment,
                odometry=self.settings.odometry,
                hands=self.settings.hands,
                hand_config=self.hand_config() if self.settings.hands else None,
            )

        try:
            pipeline = build(self.mode, self.task)
        except ValueError as exc:
            if self.mode == "none":
                raise
            # e.g. the task needs parts this source lacks: keep tracking and say why the mode is off
            self.worker.report("mode", f"{self.mode} mode unavailable on {self.source_spec}: {exc}")
            self.mode, self.task = "none", None
            pipeline = build("none", None)
        if self.calibrations:  # colours learnt from boxes outlive a source that loops or reconnects
            pipeline.detector = self.detector_for(pipeline)
        return pipeline

    def forget_scene(self) -> None:
        """Another source: parts placed by boxes, colour calibrations and identical parts belonged to the old one
        (its camera, light and objects)."""
        self.user_poses.clear()
        self.calibrations.clear()
        self.identical.clear()

    def detector_for(self, pipeline: AssemblyPipeline) -> Any:
        """The colour detector of ``pipeline``'s parts: preset ranges, replaced by the calibrations in force."""
        from tracker.perception.color_detection import ColorDetector

        coloured = [p for p in pipeline.parts if p.color is not None]
        ranges = dict(ColorDetector.from_parts(coloured).ranges) if coloured else {}
        names = {p.name for p in pipeline.parts}
        ranges.update({c.part: c.range for c in self.calibrations if c.part in names})
        return ColorDetector(ranges) if ranges else None

    # -------------------------------------------------------------- sessions
    def start_session(
        self, apply: Callable[[], None] | None = None, source: str | None = None, mode_task: tuple | None = None
    ) -> None:
        """End the current session and start a new one in one database transaction, recorded with ``source`` and
        ``mode_task`` = (mode, task) (default: those in force); only once it committed, run ``apply()`` (the change
        that starts the session). A storage error (:class:`app.storage.StorageError`) leaves everything as it was.
        A read-only database records no session."""
        mode, task = mode_task if mode_task is not None else (self.mode, self.task)
        with self._lock:
            new_id = None
            if not self.storage.read_only:
                new_id = self.storage.switch_session(
                    self.session_id, self.session_frames(), source or self.source_spec, mode, task,
                    station=self.settings.station,
                )
            if apply is not None:
                apply()
            self.session_id = new_id
            self._session_frames0 = self.worker.frames_processed
            self.results.switch(new_id, mode)

    def end_session(self) -> None:
        """Record the end of the current session (a storage error is logged: the server is stopping)."""
        self.results.switch(None, None)
        if self.session_id is not None:
            try:
                self.storage.end_session(self.session_id, self.session_frames())
            except StorageError as exc:
                log.error("%s", exc)
            self.session_id = None

    def session_frames(self) -> int:
        return self.worker.frames_processed - self._session_frames0

    # -------------------------------------------------------------- life cycle
    def startup(self) -> None:
        s = self.settings
        self.results.start()
        if s.viser_port:
            try:
                from app.scene import Scene, SceneUpdater

                self.scene = Scene(host=s.host, port=s.viser_port, render_fps=s.scene_render_fps)
                self.scene_updater = SceneUpdater(self.scene, self.worker, max_hz=s.scene_hz)
                self.scene_updater.start()
            except Exception as exc:  # noqa: BLE001 - the panel works without the 3D view
                self.worker.report("scene", f"viser scene unavailable: {exc}")
        if s.autostart:
            self.worker.start()
            try:
                self.start_session()
            except StorageError as exc:  # the stream runs without a recorded session; /api/status says why
                log.error("%s", exc)

    def shutdown(self) -> None:
        self.end_session()
        self.worker.stop()
        self.results.stop()
        self._close_process_source()
        if self.scene_updater is not None:
            self.scene_updater.stop()
        if self.scene is not None:
            self.scene.stop()


def safe_metadata(src: FrameSource) -> dict[str, Any]:
    try:
        meta = src.metadata()
    except Exception:  # noqa: BLE001
        return {}
    out = {}
    for k, v in meta.items():
        if isinstance(v, str | int | float | bool) or v is None:
            out[k] = v
        elif isinstance(v, dict | list):
            out[k] = v
    return out
