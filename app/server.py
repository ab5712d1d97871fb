"""The FastAPI application: the panel (``/``), the teacher editor (``/teacher``), REST API and the ``/ws`` stream.

``create_app(settings)`` wires storage (SQLite), teacher auth, the pipeline worker thread and the viser
scene; the worker starts with the app (lifespan) and every endpoint only reads its latest snapshot or
queues a command for it, so HTTP handling never waits for a frame to be processed.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from collections.abc import Callable
from concurrent.futures import TimeoutError as FutureTimeout
from importlib import metadata
from pathlib import Path
from typing import Annotated, Any

from fastapi import Depends, FastAPI, Header, HTTPException, Request, Response, WebSocket, WebSocketDisconnect
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse
from fastapi.staticfiles import StaticFiles
from pydantic import ValidationError

from app import api_models as m
from app.auth import TeacherAuth
from app.settings import Settings
from app.storage import Storage
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


def _version() -> str:
    try:
        return metadata.version("assembly-agent")
    except metadata.PackageNotFoundError:
        return "0.0.0"


def open_source_spec(spec: str, realtime: bool = False, seed: int = 0) -> FrameSource:
    """Open ``sim:<scenario>``, ``recording:<dir>`` or ``camera:<n>`` through the sources registry.

    The server opens simulated and recorded sources unpaced (``realtime=False``): the worker paces them
    itself at their frame rate and skips frames that became stale (see :class:`app.worker.PipelineWorker`).
    """
    from tracker.sources.registry import open_source

    return open_source(spec, realtime=realtime, seed=seed, loop=False)


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


class AppState:
    """Everything the endpoints share: settings, storage, auth, worker, scene and the current selection."""

    def __init__(self, settings: Settings, open_source: Callable[[str], FrameSource] | None = None) -> None:
        self.settings = settings
        self.storage = Storage(settings.database_path())
        self.auth = TeacherAuth(self.storage, settings.teacher_password)
        self.source_spec = settings.source_spec()
        self.mode = settings.mode
        self.task = settings.task
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
        )
        self.scene = None
        self.scene_updater = None
        self.session_id: int | None = None
        self.boxes: list[m.BoxResponse] = []
        self.user_poses: dict[str, Any] = {}  # parts placed by drawn boxes: kept when a source loops or reconnects
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

    def resolve_task(self, mode: str, ref: str | None) -> Any:
        """The task object for a reference: a preset id, or ``teacher:<n>`` (a stored sentence task)."""
        if ref is None or mode == "none":
            return None
        if ref.startswith("teacher:"):
            try:
                task_id = int(ref.split(":", 1)[1])
            except ValueError as exc:
                raise ValueError(f"task {ref!r}: expected teacher:<number>") from exc
            rec = self.storage.get_task(task_id)
            if rec is None:
                raise ValueError(f"task {ref!r}: no teacher task with id {task_id}")
            if mode != "learning":
                raise ValueError(f"task {ref!r} is a sentence task: select the learning mode for it")
            return SentenceTask(**rec["data"])
        from tracker.assembly import load_preset

        task = load_preset(ref)
        if task.mode != mode:
            raise ValueError(f"task {ref!r} is a {task.mode} task, not a {mode} task")
        return task

    def _make_pipeline(self, src: FrameSource) -> AssemblyPipeline:
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

        def build(mode: str, task: str | None) -> AssemblyPipeline:
            return AssemblyPipeline(
                list(parts),
                src.intrinsics,
                mode=None if mode == "none" else mode,
                task=self.resolve_task(mode, task),
                config=config,
                seed=self.settings.seed,
                initial_poses=poses,
                table_recheck_s=self.settings.table_recheck_s,
                source_info={"spec": self.source_spec, **_safe_metadata(src)},
                auto_place=self.settings.auto_place,
                auto_place_interval_s=self.settings.auto_place_interval_s,
            )

        try:
            return build(self.mode, self.task)
        except ValueError as exc:
            if self.mode == "none":
                raise
            # e.g. the task needs parts this source lacks: keep tracking and say why the mode is off
            self.worker.report("mode", f"{self.mode} mode unavailable on {self.source_spec}: {exc}")
            self.mode, self.task = "none", None
            return build("none", None)

    # -------------------------------------------------------------- sessions
    def start_session(self) -> None:
        with self._lock:
            self.end_session()
            self.session_id = self.storage.start_session(self.source_spec, self.mode, self.task)
            self._session_frames0 = self.worker.frames_processed

    def end_session(self) -> None:
        if self.session_id is not None:
            self.storage.end_session(self.session_id, self.worker.frames_processed - self._session_frames0)
            self.session_id = None

    def session_frames(self) -> int:
        return self.worker.frames_processed - self._session_frames0

    # -------------------------------------------------------------- life cycle
    def startup(self) -> None:
        s = self.settings
        if s.viser_port:
            try:
                from app.scene import Scene, SceneUpdater

                self.scene = Scene(host=s.host, port=s.viser_port)
                self.scene_updater = SceneUpdater(self.scene, self.worker)
                self.scene_updater.start()
            except Exception as exc:  # noqa: BLE001 - the panel works without the 3D view
                self.worker.report("scene", f"viser scene unavailable: {exc}")
        if s.autostart:
            self.worker.start()
            self.start_session()

    def shutdown(self) -> None:
        self.end_session()
        self.worker.stop()
        self._close_process_source()
        if self.scene_updater is not None:
            self.scene_updater.stop()
        if self.scene is not None:
            self.scene.stop()


def _no_task(task_id: int) -> HTTPException:
    """The 404 for a task id the store does not have."""
    return HTTPException(404, f"no task with id {task_id}")


def _found(record, task_id: int):
    """``record`` itself, or a 404 naming the task id when the store had no such task."""
    if record is None:
        raise _no_task(task_id)
    return record


def _safe_metadata(src: FrameSource) -> dict[str, Any]:
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


def _friendly(err: dict[str, Any]) -> str:
    """A plain-language version of a pydantic error message (for forms)."""
    kind, ctx, msg = err.get("type", ""), err.get("ctx") or {}, str(err.get("msg", ""))
    if kind == "string_too_short" and ctx.get("min_length") == 1:
        return "must not be empty"
    if kind == "too_short" and "min_length" in ctx:
        n = ctx["min_length"]
        what = "words" if err.get("loc", [None, None])[-1] == "words" else "items"
        return f"give at least {n} {what}"
    if kind == "missing":
        return "is required"
    if kind == "extra_forbidden":
        return "is not a known field"
    return msg.removeprefix("Value error, ")


def _task_record(rec: dict[str, Any]) -> m.TaskRecord:
    return m.TaskRecord(
        id=rec["id"],
        ref=f"teacher:{rec['id']}",
        task=SentenceTask(**rec["data"]),
        created_at=rec["created_at"],
        updated_at=rec["updated_at"],
    )


def create_app(settings: Settings | None = None, open_source: Callable[[str], FrameSource] | None = None) -> FastAPI:
    """The web application. ``open_source(spec)`` replaces the source registry (tests use it)."""
    settings = settings or Settings()
    state = AppState(settings, open_source)

    def _on_worker(apply: Callable[[Any, Any], Any]) -> Any:
        """Run ``apply(pipeline, latest frame)`` on the worker thread and return its result; a busy worker is a 503,
        a LookupError (nothing to act on yet) a 409, a ValueError (bad request) a 422."""
        try:
            return state.worker.submit(apply).result(timeout=COMMAND_TIMEOUT_S)
        except FutureTimeout as exc:
            raise HTTPException(503, "the pipeline is busy; try again") from exc
        except LookupError as exc:
            raise HTTPException(409, str(exc)) from exc
        except ValueError as exc:
            raise HTTPException(422, str(exc)) from exc

    @contextlib.asynccontextmanager
    async def lifespan(_app: FastAPI):
        state.startup()
        try:
            yield
        finally:
            state.shutdown()

    app = FastAPI(
        title="Assembly Agent",
        version=_version(),
        description="Tracks coloured parts on a table and guides the user (guidance, guess and learning modes). "
        "Live state streams on the /ws websocket (one JSON snapshot per processed frame).",
        lifespan=lifespan,
    )
    app.state.assembly = state

    @app.exception_handler(RequestValidationError)
    async def validation_error(_request: Request, exc: RequestValidationError) -> JSONResponse:
        """422 with FastAPI's usual ``detail`` list (loc, msg, type), messages in plain language."""
        detail = [
            {"loc": list(e.get("loc", [])), "msg": _friendly(e), "type": e.get("type", "")} for e in exc.errors()
        ]
        return JSONResponse({"detail": detail}, status_code=422)
    app.mount("/static", StaticFiles(directory=WEB_DIR / "static"), name="static")

    def teacher(
        request: Request,
        x_teacher_password: Annotated[str | None, Header()] = None,
        authorization: Annotated[str | None, Header()] = None,
    ) -> None:
        """Editing requires the teacher password (header), a login token (cookie) or ``Bearer <token>``."""
        if not state.auth.is_configured:
            raise HTTPException(403, "no teacher password is set yet: set one on the /teacher page first")
        token = request.cookies.get("teacher_token")
        if authorization and authorization.lower().startswith("bearer "):
            token = authorization[7:].strip()
        if state.auth.check_token(token) or state.auth.check_password(x_teacher_password):
            return
        raise HTTPException(401, "wrong or missing teacher password")

    needs_teacher = [Depends(teacher)]

    # ---------------------------------------------------------------- pages
    @app.get("/", include_in_schema=False)
    def index() -> FileResponse:
        return FileResponse(WEB_DIR / "templates" / "index.html")

    @app.get("/teacher", include_in_schema=False)
    def teacher_page() -> FileResponse:
        return FileResponse(WEB_DIR / "templates" / "teacher.html")

    # ---------------------------------------------------------------- status, sources, modes
    @app.get("/api/status", response_model=m.Status, tags=["status"])
    def status() -> m.Status:
        pipeline = state.worker.pipeline
        snap = state.worker.latest
        return m.Status(
            version=_version(),
            source=state.source_spec,
            mode=state.mode,
            task=state.task,
            parts=[p.name for p in pipeline.parts] if pipeline else [],
            viser_port=state.scene.port if state.scene is not None else None,
            session_id=state.session_id,
            worker=m.WorkerStatus(**state.worker.status()),
            instruction=snap.instruction if snap else "",
        )

    @app.get("/api/sources", response_model=m.SourcesResponse, tags=["sources"])
    def sources() -> m.SourcesResponse:
        src = state.worker.source
        return m.SourcesResponse(
            current=state.source_spec, metadata=_safe_metadata(src) if src else {}, available=available_sources()
        )

    @app.post("/api/sources", response_model=m.SourcesResponse, tags=["sources"])
    def select_source(body: m.SourceSelect) -> m.SourcesResponse:
        kind = body.source.split(":", 1)[0]
        if kind not in ("sim", "recording", "camera"):
            raise HTTPException(422, f"source {body.source!r}: expected sim:<scenario>, recording:<dir> or camera:<n>")
        state.source_spec = body.source
        state.user_poses.clear()
        state.worker.reset()
        state.start_session()
        return sources()

    def _tasks() -> list[m.TaskRef]:
        refs: list[m.TaskRef] = []
        try:
            from tracker.assembly import list_presets

            for p in list_presets():
                refs.append(m.TaskRef(id=p["id"], title=p["title"], mode=p["mode"], origin="preset"))
        except Exception as exc:  # noqa: BLE001 - a broken preset must not hide the teacher tasks
            log.warning("task presets: %s", exc)
        for rec in state.storage.list_tasks():
            data = rec["data"]
            refs.append(
                m.TaskRef(
                    id=f"teacher:{rec['id']}",
                    title=str(data.get("source_sentence", "")),
                    mode="learning",
                    origin="teacher",
                )
            )
        return refs

    @app.get("/api/modes", response_model=m.ModesResponse, tags=["modes"])
    def modes() -> m.ModesResponse:
        return m.ModesResponse(
            modes=["guidance", "guess", "learning", "none"], current=state.mode, task=state.task, tasks=_tasks()
        )

    @app.post("/api/modes", response_model=m.ModesResponse, tags=["modes"], responses={422: {"model": m.Message}})
    def select_mode(body: m.ModeSelect) -> m.ModesResponse:
        try:
            task_obj = state.resolve_task(body.mode, body.task)
        except (ValueError, ValidationError) as exc:
            raise HTTPException(422, str(exc)) from exc
        mode = None if body.mode == "none" else body.mode

        def apply(pipeline, _frame):
            if pipeline is not None:
                pipeline.set_mode(mode, task_obj)

        try:
            state.worker.submit(apply).result(timeout=COMMAND_TIMEOUT_S)
        except FutureTimeout as exc:
            raise HTTPException(503, "the pipeline is busy; try again") from exc
        except Exception as exc:  # noqa: BLE001 - e.g. the task does not fit the source's parts
            raise HTTPException(422, f"cannot switch to {body.mode}: {exc}") from exc
        state.mode, state.task = body.mode, body.task
        return modes()

    # ---------------------------------------------------------------- sessions
    def _sessions() -> m.SessionsResponse:
        rows = state.storage.list_sessions()
        for r in rows:
            if r["id"] == state.session_id:
                r["frames"] = state.session_frames()
        return m.SessionsResponse(current=state.session_id, sessions=[m.SessionInfo(**r) for r in rows])

    @app.get("/api/sessions", response_model=m.SessionsResponse, tags=["sessions"])
    def sessions() -> m.SessionsResponse:
        return _sessions()

    @app.post("/api/sessions", response_model=m.SessionsResponse, tags=["sessions"])
    def session_action(body: m.SessionAction) -> m.SessionsResponse:
        w = state.worker
        if body.action == "start":
            w.start()
            if state.session_id is None:
                state.start_session()
        elif body.action == "pause":
            w.pause()
        else:
            state.user_poses.clear()
            w.reset()
            w.start()
            state.start_session()
        return _sessions()

    # ---------------------------------------------------------------- colour image and boxes
    @app.get(
        "/api/frame.jpg",
        tags=["stream"],
        response_class=Response,
        responses={200: {"content": {"image/jpeg": {}}}, 503: {"model": m.Message}},
    )
    def frame_jpeg() -> Response:
        got = state.worker.jpeg(settings.jpeg_quality)
        if got is None:
            raise HTTPException(503, "no frame yet")
        index, data = got
        return Response(
            data, media_type="image/jpeg", headers={"Cache-Control": "no-store", "X-Frame-Index": str(index)}
        )

    @app.post(
        "/api/boxes",
        response_model=m.BoxResponse,
        tags=["stream"],
        responses={409: {"model": m.Message}, 422: {"model": m.Message}},
    )
    def draw_box(body: m.BoxRequest) -> m.BoxResponse:
        rect = (body.x, body.y, body.w, body.h)

        def apply(pipeline: AssemblyPipeline | None, frame):
            if pipeline is None or frame is None:
                raise LookupError("no frame processed yet")
            name = body.part or pipeline.guess_part(frame.color, rect)
            pipeline.part(name)
            if body.action == "calibrate":
                pipeline.calibrate_color(name, frame.color, rect)
                return name, None, frame.index
            pose = pipeline.pose_from_rect(name, rect, frame.depth)
            pipeline.set_part_pose(name, pose)
            state.user_poses[name] = pose
            return name, pose, frame.index

        name, pose, index = _on_worker(apply)
        box = m.BoxResponse(
            part=name,
            action=body.action,
            rect=list(rect),
            pose=None if pose is None else pose.to_dict(),
            frame_index=index,
        )
        state.boxes.append(box)
        del state.boxes[:-50]
        return box

    @app.post(
        "/api/parts/auto-place",
        response_model=m.AutoPlaceResponse,
        tags=["stream"],
        responses={409: {"model": m.Message}, 422: {"model": m.Message}, 503: {"model": m.Message}},
    )
    def auto_place(body: m.AutoPlaceRequest | None = None) -> m.AutoPlaceResponse:
        """Find the parts (default: those without a pose) resting on the table in the latest frame and track
        them from there; a part that is not found is reported in its result and stays untracked."""
        names = None if body is None else body.names

        def apply(pipeline: AssemblyPipeline | None, frame):
            if pipeline is None or frame is None:
                raise LookupError("no frame processed yet")
            results = pipeline.auto_place(frame, names)
            for name, r in results.items():
                if "error" not in r:
                    state.user_poses[name] = pipeline.poses[name]
            return results, frame.index

        results, index = _on_worker(apply)
        return m.AutoPlaceResponse(frame_index=index, results={k: m.AutoPlaceResult(**v) for k, v in results.items()})

    @app.get("/api/boxes", response_model=m.BoxList, tags=["stream"])
    def list_boxes() -> m.BoxList:
        return m.BoxList(boxes=state.boxes)

    @app.get("/api/snapshot", response_model=m.SnapshotModel, tags=["stream"], responses={503: {"model": m.Message}})
    def snapshot() -> dict:
        """The latest processed frame (the same JSON as one ``/ws`` message)."""
        snap = state.worker.latest
        if snap is None:
            raise HTTPException(503, "no frame processed yet")
        return snap.to_dict()

    # ---------------------------------------------------------------- teacher auth
    @app.get("/api/auth", response_model=m.AuthStatus, tags=["teacher"])
    def auth_status(request: Request) -> m.AuthStatus:
        return m.AuthStatus(
            configured=state.auth.is_configured, logged_in=state.auth.check_token(request.cookies.get("teacher_token"))
        )

    @app.post(
        "/api/auth/setup",
        response_model=m.AuthStatus,
        tags=["teacher"],
        responses={403: {"model": m.Message}, 422: {"model": m.Message}},
    )
    def auth_setup(body: m.PasswordBody, response: Response) -> m.AuthStatus:
        try:
            state.auth.setup(body.password)
        except PermissionError as exc:
            raise HTTPException(403, str(exc)) from exc
        except ValueError as exc:
            raise HTTPException(422, str(exc)) from exc
        token = state.auth.login(body.password)
        response.set_cookie("teacher_token", token or "", httponly=True, samesite="strict")
        return m.AuthStatus(configured=True, logged_in=True)

    @app.post(
        "/api/auth/login",
        response_model=m.AuthStatus,
        tags=["teacher"],
        responses={401: {"model": m.Message}, 403: {"model": m.Message}},
    )
    def auth_login(body: m.PasswordBody, response: Response) -> m.AuthStatus:
        if not state.auth.is_configured:
            raise HTTPException(403, "no teacher password is set yet")
        token = state.auth.login(body.password)
        if token is None:
            raise HTTPException(401, "wrong teacher password")
        response.set_cookie("teacher_token", token, httponly=True, samesite="strict")
        return m.AuthStatus(configured=True, logged_in=True)

    @app.post("/api/auth/logout", response_model=m.AuthStatus, tags=["teacher"])
    def auth_logout(request: Request, response: Response) -> m.AuthStatus:
        state.auth.logout(request.cookies.get("teacher_token"))
        response.delete_cookie("teacher_token")
        return m.AuthStatus(configured=state.auth.is_configured, logged_in=False)

    # ---------------------------------------------------------------- sentence tasks
    @app.get("/api/tasks", response_model=m.TaskList, tags=["tasks"])
    def list_tasks() -> m.TaskList:
        return m.TaskList(tasks=[_task_record(r) for r in state.storage.list_tasks()])

    @app.post(
        "/api/tasks",
        response_model=m.TaskRecord,
        status_code=201,
        tags=["tasks"],
        dependencies=needs_teacher,
        responses={401: {"model": m.Message}, 403: {"model": m.Message}},
    )
    def create_task(body: SentenceTask) -> m.TaskRecord:
        return _task_record(state.storage.create_task(body.model_dump(mode="json")))

    @app.get("/api/tasks/{task_id}", response_model=m.TaskRecord, tags=["tasks"], responses={404: {"model": m.Message}})
    def get_task(task_id: int) -> m.TaskRecord:
        return _task_record(_found(state.storage.get_task(task_id), task_id))

    @app.put(
        "/api/tasks/{task_id}",
        response_model=m.TaskRecord,
        tags=["tasks"],
        dependencies=needs_teacher,
        responses={401: {"model": m.Message}, 403: {"model": m.Message}, 404: {"model": m.Message}},
    )
    def update_task(task_id: int, body: SentenceTask) -> m.TaskRecord:
        return _task_record(_found(state.storage.update_task(task_id, body.model_dump(mode="json")), task_id))

    @app.delete(
        "/api/tasks/{task_id}",
        response_model=m.Message,
        tags=["tasks"],
        dependencies=needs_teacher,
        responses={401: {"model": m.Message}, 403: {"model": m.Message}, 404: {"model": m.Message}},
    )
    def delete_task(task_id: int) -> m.Message:
        if not state.storage.delete_task(task_id):
            raise _no_task(task_id)
        return m.Message(detail=f"task {task_id} deleted")

    # ---------------------------------------------------------------- websocket
    @app.websocket("/ws")
    async def ws(websocket: WebSocket) -> None:
        """One JSON snapshot per processed frame; a slow client skips to the newest one."""
        await websocket.accept()
        loop = asyncio.get_running_loop()
        event = asyncio.Event()
        closed = asyncio.Event()

        def on_snapshot(_snap) -> None:
            loop.call_soon_threadsafe(event.set)

        async def watch_disconnect() -> None:
            # Notices a client that left (or a server shutdown) even while no frame arrives.
            try:
                while (await websocket.receive())["type"] != "websocket.disconnect":
                    pass
            except (WebSocketDisconnect, RuntimeError):
                pass
            finally:
                closed.set()
                event.set()

        state.worker.add_listener(on_snapshot)
        watcher = asyncio.create_task(watch_disconnect())
        sent = -1
        try:
            while not closed.is_set():
                event.clear()  # cleared before reading: a snapshot published from now on wakes us again
                got = state.worker.snapshot_json()  # JSON encoded once per snapshot for every client
                if got is not None and got[0] != sent:
                    sent = got[0]
                    await websocket.send_text(got[1])
                    continue
                with contextlib.suppress(asyncio.TimeoutError):
                    await asyncio.wait_for(event.wait(), timeout=5.0)
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            state.worker.remove_listener(on_snapshot)
            watcher.cancel()

    return app
