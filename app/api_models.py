"""Pydantic models of the HTTP API (requests and responses); together they are the OpenAPI contract.

Teacher sentence tasks are validated with :class:`tracker.assembly.SentenceTask` (the task-file model of
the assembly package), so the editor and the task files accept exactly the same sentences.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from tracker.assembly import SentenceTask

ModeName = Literal["guidance", "guess", "learning", "none"]
MAX_IMAGE_PX = 10_000
"""Upper bound of box coordinates (pixels); the box must also lie inside the frame's image."""
Pixel = Annotated[float, Field(ge=0, le=MAX_IMAGE_PX, allow_inf_nan=False, description="pixels from the left/top")]
Extent = Annotated[float, Field(gt=0, le=MAX_IMAGE_PX, allow_inf_nan=False, description="box width/height, pixels")]
MAX_PARTS = 64
MAX_PASSWORD_CHARS = 1024
PartName = Annotated[str, Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$")]
"""A part's name as the API accepts it (the parts of a source have such names)."""


class ErrorEntry(BaseModel):
    time: float = Field(description="wall-clock time, seconds since the epoch")
    where: str = Field(description="source, frame or pipeline")
    message: str


class WorkerStatus(BaseModel):
    state: str = Field(description="starting | running | paused | error | finished | stopped")
    paused: bool
    frames_processed: int
    frames_skipped: int
    frames_dropped: int = Field(0, description="stale frames skipped because the pipeline was busy (real time)")
    source_opens: int
    frame_index: int | None
    fps: float
    errors: list[ErrorEntry]


class StorageStatus(BaseModel):
    path: str = Field(description="the SQLite file, or the PostgreSQL URL without its password")
    read_only: bool = Field(description="served read-only (damaged or unwritable at start): changes get 503")
    problem: str | None = Field(description="what is wrong with the database, or null when it works")


class Status(BaseModel):
    """``GET /api/status``."""

    version: str
    source: str
    mode: ModeName
    task: str | None
    parts: list[str]
    viser_port: int | None = Field(description="port of the viser 3D scene on this host, or null when disabled")
    session_id: int | None
    worker: WorkerStatus
    instruction: str
    storage: StorageStatus


class SourceInfo(BaseModel):
    spec: str = Field(description="what to pass to --source, e.g. sim:guess-2")
    kind: Literal["sim", "recording", "camera"]
    description: str = ""


class SourcesResponse(BaseModel):
    """``GET /api/sources``: the current source and the ones this server can open."""

    current: str
    metadata: dict[str, Any]
    available: list[SourceInfo]


class SourceSelect(BaseModel):
    source: str = Field(min_length=3, max_length=1024, description="sim:<scenario> | recording:<dir> | camera:<n>")


class TaskRef(BaseModel):
    id: str = Field(description="preset id, or teacher:<n> for a teacher's sentence task")
    title: str
    mode: Literal["guidance", "guess", "learning"]
    origin: Literal["preset", "teacher"]


class ModeChoice(BaseModel):
    """One entry of the panel's task list: a task of a mode on a source (the current one, or a simulated
    scenario built for the task: choosing it switches mode, task and source together)."""

    mode: ModeName
    task: str | None
    title: str
    source: str
    switches_source: bool


class ModesResponse(BaseModel):
    """``GET /api/modes``: the mode, task and source in force, every task, and the choices that fit."""

    modes: list[str]
    current: ModeName
    task: str | None
    source: str = ""
    tasks: list[TaskRef]
    choices: list[ModeChoice] = []


class ModeSelect(BaseModel):
    """``POST /api/modes``: switch the mode (and optionally its task; default: the mode's preset) and, with
    ``source``, the simulated scene it runs on (from the mode's choices; other sources: ``/api/sources``)."""

    mode: ModeName
    task: str | None = Field(None, max_length=100, description="preset id or teacher:<n>")
    source: str | None = Field(None, max_length=100, description="sim:<scenario> to switch to with the mode")


class SessionAction(BaseModel):
    action: Literal["start", "pause", "reset"]


class SessionInfo(BaseModel):
    id: int
    started_at: float
    ended_at: float | None
    source: str
    mode: str | None
    task: str | None
    frames: int


class SessionsResponse(BaseModel):
    current: int | None
    sessions: list[SessionInfo]


class BoxRequest(BaseModel):
    """``POST /api/boxes``: a rectangle drawn on the colour image (pixels of the full-size image)."""

    x: Pixel
    y: Pixel
    w: Extent
    h: Extent
    action: Literal["track", "calibrate"] = "track"
    part: PartName | None = Field(None, description="part name; default: the part whose colour matches the rectangle")


class BoxResponse(BaseModel):
    part: str
    action: Literal["track", "calibrate"]
    rect: list[float] = Field(description="[x, y, w, h] pixels")
    pose: dict[str, list[float]] | None = Field(None, description="camera-frame pose {t, q} of the new box")
    frame_index: int | None


class BoxList(BaseModel):
    """``GET /api/boxes``: the boxes users drew since the server started (newest last)."""

    boxes: list[BoxResponse]


class IdenticalBox(BaseModel):
    """``POST /api/identical-parts``: a box drawn around one of several parts of the same colour."""

    colour: str = Field(min_length=1, max_length=40, description="the parts' colour (a part name or preset colour)")
    x: Pixel
    y: Pixel
    w: Extent
    h: Extent


class IdenticalParts(BaseModel):
    """The identical parts tracked in the image (their boxes per frame are in each snapshot's identical_parts)."""

    colour: str | None
    parts: list[str]


class CalibrationInfo(BaseModel):
    part: str
    frame_index: int | None = Field(None, description="the frame whose pixels the range was learnt from")


class CalibrationList(BaseModel):
    """``GET /api/calibration``: the colour calibrations in force, oldest first (undo removes the last)."""

    calibrations: list[CalibrationInfo]


class AutoPlaceRequest(BaseModel):
    """``POST /api/parts/auto-place``: which parts to find on the table (default: every part without a pose)."""

    model_config = ConfigDict(extra="forbid")

    names: list[PartName] | None = Field(
        None, max_length=MAX_PARTS, description="part names; a tracked part that is named is placed again"
    )


class AutoPlaceResult(BaseModel):
    """One part's outcome: its camera-frame pose and fit residual, or why it was not found."""

    t: list[float] | None = Field(None, description="[x, y, z] metres, camera frame")
    q: list[float] | None = Field(None, description="[x, y, z, w]")
    residual_mm: float | None = Field(None, description="median point-to-surface distance of its depth points")
    method: str | None = None
    error: str | None = Field(None, description="why the part was not found (it stays untracked)")


class AutoPlaceResponse(BaseModel):
    frame_index: int
    results: dict[str, AutoPlaceResult] = Field(description="per part; empty when every part already had a pose")


class SnapshotModel(BaseModel):
    """One processed frame, as sent on ``/ws`` (see :class:`tracker.snapshot.Snapshot`; camera-frame poses)."""

    frame_index: int
    time: float = Field(description="frame timestamp, seconds since the source started")
    wall_time: float = Field(description="time.time() when the frame arrived from the source")
    poses: dict[str, dict[str, list[float | None]]] = Field(description="{part: {t: [x,y,z] m, q: [x,y,z,w]}}")
    boxes: dict[str, list[float | None]] = Field(description="{part: [u0, v0, u1, v1]} projected estimate, pixels")
    detections: dict[str, dict[str, Any]] = Field(description="{part: {center, bbox [x,y,w,h], score, area}}")
    connections: list[dict[str, Any]]
    mode: str | None
    mode_state: dict[str, Any]
    instruction: str
    table: dict[str, Any] | None
    fps: float
    timings: dict[str, float]
    source: dict[str, Any]
    errors: list[str]
    carried: list[str] = Field([], description="parts currently hidden inside a hand and moved with it")
    hands: list[dict[str, Any]] = Field(
        [], description="tracked hands (hand tracking on): {id, box [u0,v0,u1,v1], score, velocity, touching, holding, "
        "text e.g. 'holding the red cube', position [x,y,z] m or null}")
    camera_pose: dict[str, Any] | None = Field(
        None, description="camera odometry: {t, q, ok}, the camera's pose in the world frame (the first camera "
        "frame); null when odometry is off")
    image_size: list[int]
    identical_parts: dict[str, dict[str, Any]] = Field(
        {}, description="{name: {bbox [x,y,w,h], center, score, seen}}: same-colour parts told apart in the image"
    )


class TaskRecord(BaseModel):
    """A stored teacher task."""

    id: int
    ref: str = Field(description="what to pass as task to POST /api/modes, e.g. teacher:3")
    task: SentenceTask
    created_at: float
    updated_at: float


class TaskList(BaseModel):
    tasks: list[TaskRecord]


class PasswordBody(BaseModel):
    password: str = Field(min_length=1, max_length=MAX_PASSWORD_CHARS)


class AuthStatus(BaseModel):
    configured: bool = Field(description="a teacher password exists")
    logged_in: bool


class Message(BaseModel):
    detail: str


# ---------------------------------------------------------------------- learner results (teacher only)
class ResultSession(BaseModel):
    """One session's results; times are wall-clock seconds since the epoch, durations seconds."""

    id: int
    station: str | None
    mode: str | None
    task: str = Field(description="the task reference (a mode's default task when none was named)")
    started_at: float
    ended_at: float | None
    completed_at: float | None = Field(description="when the task was first completed, or null")
    steps_total: int | None
    steps_done: int = Field(description="steps finished in the session's best attempt")
    wrong_placements: int
    hints: int
    time_s: float = Field(description="seconds spent on steps, all attempts")


class ResultStep(BaseModel):
    """One step index over all matching sessions and attempts."""

    step: int = Field(description="1-based step index")
    n: int = Field(description="attempts at this step (finished or not)")
    mean_time_s: float | None = Field(description="mean seconds of the finished ones")
    error_rate: float = Field(description="share (0..1) of attempts with at least one wrong placement")
    hints: int


class ResultGroup(BaseModel):
    """Totals of the sessions of one task or one station (``task`` or ``station`` names it)."""

    task: str | None = None
    station: str | None = None
    sessions: int
    completed: int
    mean_step_time_s: float | None
    error_rate: float | None
    wrong_placements: int
    hints: int


class ResultFilters(BaseModel):
    task: str | None
    station: str | None


class Results(BaseModel):
    """``GET /api/results``: the matching sessions (newest first), per step, per task, per station, and the
    tasks and stations there are (for the filters)."""

    filters: ResultFilters
    tasks: list[str]
    stations: list[str]
    sessions: list[ResultSession]
    steps: list[ResultStep]
    by_task: list[ResultGroup]
    by_station: list[ResultGroup]
