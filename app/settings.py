"""Server settings (pydantic-settings): command-line flags override environment variables ``ASSEMBLY_AGENT_*``.

* ``host``/``port``: where the HTTP server listens; ``viser_port``: the 3D scene's server (0 = off).
* ``database``: where teacher tasks, sessions and learner results live: a SQLite file path or ``sqlite:///path``
  URL (default, no set-up), or a PostgreSQL server ``postgresql://user:password@host:port/dbname`` shared by
  several stations (:mod:`app.database`).
* ``database_wait_s``: at start, keep trying this many seconds while a PostgreSQL database is unreachable
  (a server started together with its database); 0 (default): stop at once with the message.
* ``station``: this station's name, stored with every session (the teacher's results are grouped by it);
  default: the machine's host name.
* ``teacher_password``: when set (env ``ASSEMBLY_AGENT_TEACHER_PASSWORD``), the teacher password; otherwise
  the first teacher to open ``/teacher`` sets it. It is only ever stored hashed.
* ``source``: ``sim:<scenario>`` | ``recording:<dir>`` | ``camera:<n>`` (default: the simulated scenario of
  the mode); ``mode``/``task``: the assembly mode at start and its task (preset id or ``teacher:<id>``).
* ``realtime``: pace recordings and the simulator at their frame rate, always processing the newest due
  frame (stale frames are skipped, so latency does not pile up); ``loop``: restart a finished source.
  ``realtime_ahead`` (off): produce each paced frame ahead of its due time (the frame due when its production
  ends) and hand it over when due, as a camera delivers its frames, instead of starting the simulator's render
  (or a recording's read) only once the frame is due (the pipeline then waits the render's time for every frame).
* ``source_process``: render the simulated table in a child process (parallel to the tracker; the
  simulator and the tracker both hold Python's interpreter lock while they compute).
* ``auto_place``: find parts that have no pose (a live camera, a recording without poses in objects.json)
  automatically on the table, trying again every ``auto_place_interval_s`` seconds while some are missing
  (:meth:`tracker.pipeline.AssemblyPipeline.auto_place`); off: only a drawn box or "Find parts" places them.
* Security: ``allowed_hosts``/``allowed_origins`` (Host and Origin checks against DNS rebinding and cross-site
  use; localhost, 127.0.0.1, ::1 and ``host`` are always allowed), ``recording_dirs`` (the only folders whose
  recordings the API may open), ``max_body_bytes`` (413 above), ``api_rate``/``api_burst`` and
  ``learner_rate``/``learner_burst`` (429 with ``Retry-After`` above, per client address),
  ``login_burst``/``login_refill_s`` (wrong teacher passwords allowed per client).
* ``on_damaged_database``: a damaged or unwritable database at start stops the server with a message naming
  the file (``refuse``) or is served read-only (``read-only``; changes get 503, ``/api/status`` says why).
* ``scene_hz``, ``scene_render_fps``: the 3D scene's updates per second (server → browser) and the browser's
  redraws per second at most (see :mod:`app.scene`).
* ``tracker_config``: tracker preset name or YAML/TOML path; ``seed``: random seed of tracker and modes.
* ``n_particles``: the tracker's particle count N. Default :data:`SERVER_PARTICLES` = 100 rather than the
  tracker preset's 225 (a ``tracker_config`` given without ``n_particles`` keeps its own N): on a 2-core
  machine 225 particles cannot keep up with a 30 fps source, while N = 100 tracks as accurately on the
  simulated sequences (benchmarks/results/tracker.md: translation median 1.2–1.5 mm, rotation median
  0.5–0.7°, the same as N = 225) in about half the time.
"""

from __future__ import annotations

import socket
from pathlib import Path
from typing import Literal

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from app.database import DatabaseTarget

SERVER_PARTICLES = 100
"""The server's default tracker particle count (see the module docstring)."""


class Settings(BaseSettings):
    """All knobs of ``assembly-agent serve``."""

    model_config = SettingsConfigDict(env_prefix="ASSEMBLY_AGENT_", extra="ignore")

    host: str = "127.0.0.1"
    port: int = Field(8000, ge=0, le=65535)
    viser_port: int = Field(8080, ge=0, le=65535, description="port of the viser 3D scene; 0 disables it")
    database: str = "data/assembly-agent.sqlite3"
    database_wait_s: float = Field(
        0.0,
        ge=0,
        description="seconds to keep trying at start while a PostgreSQL database is unreachable (0: fail at once)",
    )
    station: str = Field(
        default_factory=lambda: socket.gethostname() or "station",
        min_length=1,
        max_length=64,
        description="this station's name, stored with its sessions (default: the host name)",
    )
    teacher_password: str | None = None
    source: str | None = Field(None, description="default: the simulated scenario matching the mode")
    mode: Literal["guidance", "guess", "learning", "none"] = "guidance"
    task: str | None = None
    seed: int = 0
    realtime: bool = True
    realtime_ahead: bool = Field(False, description="paced sources: frames produced ahead, handed over when due")
    loop: bool = True
    source_process: bool = Field(True, description="render the simulator in a child process (parallel to tracking)")
    auto_place: bool = Field(True, description="place parts without a pose automatically when found on the table")
    auto_place_interval_s: float = Field(2.0, gt=0, description="seconds between automatic placement attempts")
    hands: bool = Field(False, description="track the hands: occluder prior for the parts, 'holding the red cube' in "
                        "the panel, connections confirmed only after the hand lets go")
    hands_worker: Literal["process", "thread"] = Field(
        "process", description="where the hand step runs beside the tracker: a child process (default) or a thread"
    )
    tracker_config: str | None = None
    n_particles: int | None = Field(
        SERVER_PARTICLES,
        ge=1,
        description="the tracker's particle count N (default 100 for real time on 2 cores; None: the preset's)",
    )
    table_recheck_s: float = Field(3.0, gt=0)
    odometry: Literal["default", "fastslam", "fused", "off"] = Field(
        "fused", description="camera ego-motion: parts kept in the world frame while the camera moves (issue 15; "
        "tracker.odometry.ego_motion.DEFAULT_MODE: idle on a fixed camera, the same poses as off)"
    )
    max_fps: float = Field(30.0, gt=0, description="upper bound on processed frames per second")
    jpeg_quality: int = Field(75, ge=10, le=100)
    scene_hz: float = Field(4.0, gt=0, le=60, description="3D scene updates sent to the browser per second at most")
    scene_render_fps: float = Field(
        8.0,
        ge=0,
        le=240,
        description="the browser redraws the 3D scene at most this often while the user is not turning the view "
        "(0: uncapped); a browser without a GPU draws it on the CPU the server needs",
    )
    autostart: bool = True
    # ---- security (see README "Security settings")
    allowed_hosts: list[str] = Field(
        default_factory=list,
        description="Host names (or addresses) the server answers to besides localhost/127.0.0.1/::1 and --host; "
        "'*' answers any (turns the DNS-rebinding protection off)",
    )
    allowed_origins: list[str] = Field(
        default_factory=list,
        description="extra page origins (scheme://host:port) allowed to open /ws and send changes; the allowed "
        "hosts are always allowed",
    )
    recording_dirs: list[str] = Field(
        default_factory=lambda: ["data"],
        description="folders whose recordings POST /api/sources may open (the --source of the command line is free)",
    )
    on_damaged_database: Literal["refuse", "read-only"] = Field(
        "refuse",
        description="a damaged or unwritable database at start: refuse to start (naming the file) or serve it "
        "read-only (changes get 503; the reason shows in /api/status and the panel)",
    )
    max_body_bytes: int = Field(256 * 1024, ge=1024, description="largest request body; larger ones get 413")
    api_rate: float = Field(100.0, gt=0, description="API requests per second per client (average)")
    api_burst: int = Field(200, ge=1, description="API requests per client at once")
    learner_rate: float = Field(2.0, gt=0, description="learner actions (mode, boxes, auto-place, start/pause) per s")
    learner_burst: int = Field(10, ge=1, description="learner actions per client at once")
    login_burst: int = Field(5, ge=1, description="wrong teacher passwords per client before waiting")
    login_refill_s: float = Field(10.0, gt=0, description="seconds until one more wrong password is allowed")

    def source_spec(self) -> str:
        """``source``, or the simulated scenario that suits ``mode`` (guidance-demo, guess-1, learning-4)."""
        if self.source:
            return self.source
        return {"guess": "sim:guess-1", "learning": "sim:learning-4"}.get(self.mode, "sim:guidance-demo")

    def database_target(self) -> DatabaseTarget:
        """Where ``database`` points (ValueError naming the accepted forms for anything else)."""
        return DatabaseTarget.parse(self.database)

    def database_path(self) -> Path:
        """The SQLite file behind ``database`` (a path or a ``sqlite:///`` URL); ValueError for a server."""
        target = self.database_target()
        if target.path is None:
            raise ValueError(
                f"database {target.display} is a PostgreSQL server: this works on SQLite files only "
                "(back up a PostgreSQL database with pg_dump, restore it with pg_restore)"
            )
        return target.path
