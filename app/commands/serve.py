"""``assembly-agent serve``: the web application (panel, teacher editor, 3D scene) on the chosen source."""

from __future__ import annotations

import argparse
import logging
import socket

from pydantic import ValidationError

log = logging.getLogger(__name__)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "serve",
        help="serve the browser panel, 3D scene and teacher editor (default: simulated table, guidance mode)",
        description="Start the web application on http://HOST:PORT. With no arguments it serves the simulated "
        "table in guidance mode on http://127.0.0.1:8000. Settings may also come from environment variables "
        "ASSEMBLY_AGENT_<NAME> (e.g. ASSEMBLY_AGENT_TEACHER_PASSWORD, ASSEMBLY_AGENT_DATABASE).",
    )
    p.add_argument(
        "--source",
        help="sim:<scenario> | recording:<dir> | camera:<n> (default: sim:guidance-demo, sim:guess-1 or "
        "sim:learning-4 to suit --mode)",
    )
    p.add_argument("--mode", choices=["guidance", "guess", "learning", "none"], help="assembly mode at start")
    p.add_argument("--task", help="task preset id (e.g. guidance-5-cubes) or teacher:<id>; default: the mode's preset")
    p.add_argument("--host", help="address to listen on (default 127.0.0.1; 0.0.0.0 for all interfaces)")
    p.add_argument("--port", type=int, help="HTTP port (default 8000)")
    p.add_argument("--viser-port", type=int, help="port of the viser 3D scene (default 8080; 0 disables it)")
    p.add_argument(
        "--database",
        help="SQLite file, sqlite:///path, or postgresql://user:password@host:port/dbname for a database shared by "
        "several stations (default data/assembly-agent.sqlite3; env ASSEMBLY_AGENT_DATABASE)",
    )
    p.add_argument(
        "--database-wait",
        type=float,
        dest="database_wait_s",
        metavar="SECONDS",
        help="at start, keep trying this long while a PostgreSQL database is unreachable (default 0; env "
        "ASSEMBLY_AGENT_DATABASE_WAIT_S)",
    )
    p.add_argument(
        "--station",
        help="this station's name, stored with its sessions and results (default: the host name; "
        "env ASSEMBLY_AGENT_STATION)",
    )
    p.add_argument("--tracker-config", help="tracker preset name or YAML/TOML settings file")
    p.add_argument(
        "--particles",
        type=int,
        dest="n_particles",
        help="the tracker's particle count N (default 100: real time on 2 cores; with --tracker-config: its own N)",
    )
    p.add_argument("--seed", type=int, help="random seed of tracker and modes")
    p.add_argument(
        "--odometry",
        choices=["default", "fastslam", "fused", "off"],
        help="camera ego-motion (default off): 'default' dense RGB-D odometry, 'fastslam' the seed's AKAZE + "
        "FastSLAM, 'fused' dense odometry checked against the table plane and the resting parts; the parts are kept "
        "in the world frame while the camera moves",
    )
    p.add_argument(
        "--no-realtime",
        dest="realtime",
        action="store_false",
        default=None,
        help="process simulated/recorded frames as fast as possible instead of at their frame rate",
    )
    p.add_argument(
        "--no-auto-place",
        dest="auto_place",
        action="store_false",
        default=None,
        help="do not look for parts without a pose automatically (draw a box or press 'Find parts' instead)",
    )
    p.add_argument(
        "--hands",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="track the hands (boxes in the colour view, 'holding the red cube', hands in the 3D scene, occluder "
        "prior for the parts, connections confirmed after the hand lets go); default off",
    )
    p.add_argument(
        "--hands-worker",
        choices=("process", "thread"),
        default=None,
        help="with --hands: run the hand step in a child process (default; its own interpreter lock and core) or in a "
        "thread of the server",
    )
    p.add_argument(
        "--allowed-host",
        action="append",
        dest="allowed_hosts",
        metavar="NAME",
        help="a host name or address browsers may use to reach the server besides localhost/127.0.0.1 and --host "
        "(repeatable; e.g. the machine's LAN address with --host 0.0.0.0; '*' turns the Host check off)",
    )
    p.add_argument(
        "--allowed-origin",
        action="append",
        dest="allowed_origins",
        metavar="URL",
        help="an extra page origin (scheme://host:port) allowed to open /ws and send changes (repeatable)",
    )
    p.add_argument(
        "--recording-dir",
        action="append",
        dest="recording_dirs",
        metavar="DIR",
        help="a folder whose recordings the panel/API may open (repeatable; default: data)",
    )
    p.add_argument(
        "--on-damaged-database",
        choices=["refuse", "read-only"],
        help="a damaged or unwritable database at start: refuse to start (default) or serve it read-only",
    )
    p.set_defaults(func=run)


def port_free(host: str, port: int) -> bool:
    """Whether a server could listen on ``host:port`` now (nothing else listening there)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn does: TIME_WAIT does not count
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def check_ports(settings) -> None:
    """A port in use ends the start with the option that changes it (instead of uvicorn's ``Errno 98``)."""
    if settings.port and not port_free(settings.host, settings.port):
        raise ValueError(
            f"port {settings.port} on {settings.host} is in use (another server is running there?): "
            f"stop it or choose another port with --port, e.g. --port {settings.port + 1}"
        )
    if settings.viser_port and not port_free(settings.host, settings.viser_port):
        raise ValueError(
            f"the 3D scene's port {settings.viser_port} is in use: choose another with --viser-port, "
            f"e.g. --viser-port {settings.viser_port + 1}, or turn the scene off with --viser-port 0"
        )


def check_source(settings) -> None:
    """A ``--source`` given on the command line must open now (the panel may still switch sources later)."""
    from app.state import open_source_spec

    spec = settings.source_spec()
    try:
        src = open_source_spec(spec, False, settings.seed)
    except Exception as exc:  # noqa: BLE001 - any failure to open is the user's to fix before starting
        raise ValueError(f"cannot open --source {spec}: {exc}") from exc
    try:
        src.close()
    except Exception:  # noqa: BLE001, S110 - it opened, which is what was checked
        pass


def run(args: argparse.Namespace) -> int:
    import uvicorn

    from app.server import create_app
    from app.settings import Settings

    overrides = {
        k: v
        for k, v in {
            "source": args.source,
            "mode": args.mode,
            "task": args.task,
            "host": args.host,
            "port": args.port,
            "viser_port": args.viser_port,
            "database": args.database,
            "station": args.station,
            "database_wait_s": args.database_wait_s,
            "tracker_config": args.tracker_config,
            "n_particles": args.n_particles,
            "seed": args.seed,
            "odometry": args.odometry,
            "realtime": args.realtime,
            "auto_place": getattr(args, "auto_place", None),
            "hands": getattr(args, "hands", None),
            "hands_worker": getattr(args, "hands_worker", None),
            "allowed_hosts": args.allowed_hosts,
            "allowed_origins": args.allowed_origins,
            "recording_dirs": args.recording_dirs,
            "on_damaged_database": args.on_damaged_database,
        }.items()
        if v is not None
    }
    try:
        settings = Settings(**overrides)
    except ValidationError as exc:
        msgs = "; ".join(f"{'.'.join(str(x) for x in e['loc'])}: {e['msg']}" for e in exc.errors())
        raise ValueError(f"invalid settings: {msgs}") from exc
    check_ports(settings)
    if args.source is not None:
        check_source(settings)
    app = create_app(settings)
    print(f"Assembly Agent: http://{settings.host}:{settings.port}/  (teacher editor: /teacher, API: /docs)")
    if settings.host in ("0.0.0.0", "::") and not settings.allowed_hosts:
        print(
            "note: other machines reach this server only by a name given with --allowed-host (e.g. this machine's "
            "LAN address); others are refused against DNS rebinding"
        )
    # no per-message compression on /ws: the panel's messages are mostly JPEG (incompressible) and compressing
    # them cost the event loop about a quarter of its time (py-spy, benchmarks/bench_server.py's browser run)
    uvicorn.run(app, host=settings.host, port=settings.port, log_level="warning", timeout_graceful_shutdown=5,
                ws_per_message_deflate=False)
    return 0
