"""Benchmark of the web server: processed frames per second, frame → websocket latency, server CPU use.

Runs ``assembly-agent serve`` as a subprocess on the simulated table (scenario guidance-demo, 5 cubes,
640×480, guidance mode, the server's default settings: tracker preset ``default`` with N = 100 particles,
simulator rendered in a child process) with one client (this script) doing what the browser panel does:
reading every ``/ws?image=1`` message, each snapshot followed by the JPEG of its frame (``--no-jpeg``:
snapshots only). Two runs: *unpaced* (``--no-realtime``: frames as fast as the pipeline takes them → throughput)
and *realtime* (the simulator at 30 fps, what a user sees; stale frames are skipped). Latency = time the
websocket message is received − the snapshot's ``wall_time``, the frame's capture time (a paced frame's
due time; an unpaced frame's start of rendering); both clocks are this machine's. CPU = user+system CPU
time of the server process and its children (the simulator's process) / wall time (100 % = one core),
from /proc. The tracker's own time per frame comes from the snapshots' ``timings``.

Then two runs with a headless Chromium showing the panel (:func:`run_browser_case`): without the embedded 3-D
scene (the baseline) and with it; panel fps, server fps, the scene's redraws and the CPU time of every process
per second and per frame the panel showed. Run it at a high priority on a shared machine (``nice -n -10``):
Chromium resets its processes' priorities (renderers 0, the GPU process's main thread -8), so the browser runs
set each Chromium thread back to the benchmark's priority, the server's (:func:`match_priority`).

Writes benchmarks/results/server.json and server.md (``--stem NAME``: NAME.json and NAME.md).

    .venv/bin/python benchmarks/bench_server.py [--seconds 20] [--particles N] [--hands] [--stem NAME]

``--hands`` adds the two websocket runs again with the hand tracker on (``serve --hands``); ``--odometry MODE`` adds
them with that camera odometry (``serve --odometry MODE``), to compare with the server's default in the same run.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

import httpx

from tracker.evaluation.machine_info import machine_info

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from app.settings import SERVER_PARTICLES  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
REALTIME_AHEAD = False
"""``--realtime-ahead``: the server's paced frames produced ahead of their due time (``realtime_ahead``)."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stat_fields(pid: int) -> list[str] | None:
    """The fields of /proc/<pid>/stat after the command name (index 0 = state), None once the process is gone."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None


def ended_children_cpu(pid: int) -> float:
    """User + system CPU seconds of the child processes of ``pid`` that ended and were waited for (cutime + cstime):
    a hand process ended and replaced during a run took its CPU time out of the live processes' sum."""
    fields = _stat_fields(pid)
    return 0.0 if fields is None else (int(fields[13]) + int(fields[14])) / os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a process (its threads), of its live child processes and of the children that
    ended and were waited for, from /proc (never decreasing while ``pid`` lives: a child replaced between two
    readings keeps its CPU time in the sum)."""
    fields = _stat_fields(pid)
    if fields is None:
        return 0.0
    ticks = os.sysconf("SC_CLK_TCK")
    total = (int(fields[11]) + int(fields[12]) + int(fields[13]) + int(fields[14])) / ticks
    children: set[int] = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            children.update(int(c) for c in (task / "children").read_text().split())
        except OSError:
            pass
    return total + sum(cpu_seconds(c) for c in children)


PROCESS_LABELS = {"frame-source": "simulator", "hand-step": "hands"}
"""OS names of the server's child processes (``tracker/os_names.py``) → the labels of the report."""


def _task_cpu(stat: Path) -> float:
    fields = stat.read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _threads(pid: int) -> dict[int, tuple[str, Path]]:
    """The threads of the server ``pid`` and of its live child processes: thread id → (``"<process>/<thread>"``,
    its /proc task directory). The process is ``server`` or its child's label (``simulator``, ``hands``, from the OS
    names the children give themselves), the thread its OS name (``pipeline-worker``, ``frame-reader``…; unnamed
    threads, e.g. the event loop and the JPEG encoder's, are ``other``; a child's first thread is ``main``)."""
    out: dict[int, tuple[str, Path]] = {}

    def add(p: int, label: str) -> None:
        children: set[int] = set()
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                comm = (task / "comm").read_text().strip()
                children.update(int(c) for c in (task / "children").read_text().split())
            except (OSError, ValueError):
                continue
            thread = "main" if task.name == str(p) and label != "server" else comm
            if thread.startswith("python") or thread in ("asyncio", "uvicorn"):
                thread = "other"
            out[int(task.name)] = (f"{label}/{thread}", task)
        for c in sorted(children):
            try:
                name = Path(f"/proc/{c}/comm").read_text().strip()
            except OSError:
                continue
            add(c, PROCESS_LABELS.get(name, name))

    add(pid, "server")
    return out


def cpu_by_thread(pid: int) -> dict[str, float]:
    """CPU seconds (user + system) of the server ``pid`` and its live child processes, by ``"<process>/<thread>"``
    (:func:`_threads`), and of its child processes that ended and were waited for as ``"ended/children"``. Threads that
    ended are missing."""
    out: dict[str, float] = {"ended/children": ended_children_cpu(pid)}
    for key, task in _threads(pid).values():
        try:
            cpu = _task_cpu(task / "stat")
        except (OSError, ValueError, IndexError):
            continue
        out[key] = out.get(key, 0.0) + cpu
    return out


def sched_by_thread(pid: int) -> dict[int, tuple[str, float, float]]:
    """Per thread of the server and its children (:func:`_threads`): thread id → (``"<process>/<thread>"``, seconds
    on a core, seconds runnable but waiting for a core), from /proc/…/schedstat (empty where the kernel has none)."""
    out: dict[int, tuple[str, float, float]] = {}
    for tid, (key, task) in _threads(pid).items():
        try:
            run_ns, wait_ns = (int(x) for x in (task / "schedstat").read_text().split()[:2])
        except (OSError, ValueError):
            continue
        out[tid] = (key, run_ns / 1e9, wait_ns / 1e9)
    return out


SCHED_THREADS = ("server/pipeline-worker", "hands/main", "simulator/main")
"""The threads whose scheduler states the report shows: the pipeline, the hand step, the simulator's rendering."""


def sched_split(before: dict[int, tuple[str, float, float]], after: dict[int, tuple[str, float, float]],
                wall_s: float) -> dict[str, dict[str, float]]:  # fmt: skip
    """Share of the wall time ``wall_s`` (%) each ``"<process>/<thread>"`` spent on a core (``run``), runnable but
    waiting for one (``runqueue``: the cores were busy) and neither (``blocked``: sleeping on a lock, a queue, a pipe,
    a timer), between two :func:`sched_by_thread` readings; threads of one key are summed (their wall time too);
    threads not alive at both readings are left out."""
    acc: dict[str, list[float]] = {}
    for tid, (key, run1, wait1) in after.items():
        if tid not in before or before[tid][0] != key:
            continue
        a = acc.setdefault(key, [0.0, 0.0, 0.0])
        a[0] += run1 - before[tid][1]
        a[1] += wait1 - before[tid][2]
        a[2] += wall_s
    out = {}
    for key, (run, wait, wall) in sorted(acc.items()):
        if wall <= 0:
            continue
        run, wait = min(run, wall), min(wait, wall)
        out[key] = {"run": round(100 * run / wall, 1), "runqueue": round(100 * wait / wall, 1),
                    "blocked": round(100 * max(wall - run - wait, 0.0) / wall, 1)}
    return out


def frame_steps(indices: list[int]) -> dict[str, float] | None:
    """Frames the source advanced between consecutive snapshots (1: none skipped), mean and largest, over the steps
    forward (a source that loops restarts its index: that step is left out); None with fewer than two snapshots."""
    steps = [b - a for a, b in zip(indices[:-1], indices[1:], strict=True) if b > a]
    if not steps:
        return None
    return {"mean": round(sum(steps) / len(steps), 2), "max": max(steps)}


def child_pids(pid: int) -> dict[int, str]:
    """The labelled child processes of the server ``pid`` (``simulator``, ``hands``: :data:`PROCESS_LABELS`): process
    id → label."""
    out = {}
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            children = [int(c) for c in (task / "children").read_text().split()]
        except (OSError, ValueError):
            continue
        for c in children:
            try:
                name = Path(f"/proc/{c}/comm").read_text().strip()
            except OSError:
                continue
            if name in PROCESS_LABELS:
                out[c] = PROCESS_LABELS[name]
    return out


def cached_kernels(directory: Path | None = None) -> int:
    """Files in numba's cache directory of this checkout's kernel sources (:func:`tracker.numba_cache.cache_dir`, or
    ``NUMBA_CACHE_DIR`` when set, as the server uses): more after a run than before it means kernels compiled during
    it (after a change of any kernel's source every kernel compiles on its first call, seconds of CPU each on the
    pipeline thread or in the hand process), and its figures are not those of the running server."""
    from tracker.numba_cache import cache_dir

    d = directory or Path(os.environ.get("NUMBA_CACHE_DIR") or cache_dir())
    try:
        return sum(1 for p in d.rglob("*") if p.suffix in (".nbi", ".nbc"))
    except OSError:
        return 0


def replaced_children(before: dict[int, str], after: dict[int, str]) -> list[str]:
    """Labels of the child processes (:func:`child_pids`) alive at the first reading and gone at the second (ended,
    and usually replaced by a new one: a hand process that hung or died): the run's figures are then not those of
    one steady process."""
    return sorted(label for c, label in before.items() if c not in after)


def cpu_split(before: dict[str, float], after: dict[str, float], frames: int) -> tuple[dict, dict]:
    """CPU ms per frame by process and by ``process/thread`` between two :func:`cpu_by_thread` readings (a process or
    thread that ended between them drops out of its key; its CPU time is under ``ended/children``, counted once it has
    been waited for)."""
    by_thread = {k: 1000.0 * (v - before.get(k, 0.0)) / max(frames, 1) for k, v in sorted(after.items())}
    by_process: dict[str, float] = {}
    for k, v in by_thread.items():
        by_process[k.split("/", 1)[0]] = by_process.get(k.split("/", 1)[0], 0.0) + v
    return ({k: round(v, 1) for k, v in by_process.items()},
            {k: round(v, 1) for k, v in by_thread.items() if v >= 0.05})


def machine_ticks(path: Path = Path("/proc/stat")) -> dict[str, int] | None:
    """The machine's CPU time since boot, all cores summed, in clock ticks from the ``cpu`` line of /proc/stat: ``busy``
    (user, nice, system, irq, softirq), ``idle`` (idle, iowait) and ``steal`` (time the host ran something else while
    this virtual machine had work); None without /proc."""
    try:
        first = path.read_text().splitlines()[0].split()
    except (OSError, IndexError):
        return None
    if first[0] != "cpu" or len(first) < 9:
        return None
    user, nice, system, idle, iowait, irq, softirq, steal = (int(x) for x in first[1:9])
    return {"busy": user + nice + system + irq + softirq, "idle": idle + iowait, "steal": steal}


def machine_split(before: dict[str, int] | None, after: dict[str, int] | None, server_cpu_s: float,
                  wall_s: float) -> dict[str, float] | None:
    """What the machine's cores did between two :func:`machine_ticks` readings, in % of one core (as ``cpu_percent``):
    ``busy`` all processes, ``other_jobs`` the busy time that is not the server's (``server_cpu_s`` seconds: the
    server, its children; this benchmark's websocket client is among the others), ``steal`` the time the host took
    from this virtual machine. A run whose CPU per frame is higher with the same code and the same frames (session
    32: 58.9 against 52.4 ms in every process alike) shows here whether other jobs or the host shared the cores."""
    if before is None or after is None or wall_s <= 0:
        return None
    tick = os.sysconf("SC_CLK_TCK")
    busy = (after["busy"] - before["busy"]) / tick
    return {"busy": round(100.0 * busy / wall_s, 1),
            "other_jobs": round(100.0 * max(busy - server_cpu_s, 0.0) / wall_s, 1),
            "steal": round(100.0 * (after["steal"] - before["steal"]) / tick / wall_s, 1)}  # fmt: skip


def machine() -> dict:
    return machine_info()


async def read_ws(url: str, seconds: float, images: bool) -> tuple[list[dict], int]:
    """Read the websocket like the panel does (``/ws?image=1``: each snapshot followed by its frame's JPEG) or,
    without ``images``, snapshots only; returns the snapshots' figures and the number of JPEGs received."""
    import websockets

    out = []
    n_jpeg = 0
    t_end = time.time() + seconds
    async with websockets.connect(url + ("?image=1" if images else ""), max_size=None) as ws:
        while time.time() < t_end:
            msg = await asyncio.wait_for(ws.recv(), timeout=30)
            now = time.time()
            if isinstance(msg, bytes):
                n_jpeg += 1
                continue
            d = json.loads(msg)
            out.append(
                {
                    "recv": now,
                    "wall": d["wall_time"],
                    "index": d["frame_index"],
                    "timings": d["timings"],
                    "errors": d["errors"],
                    "instruction": d["instruction"],
                }
            )
    return out, n_jpeg


def wait_until_processing(proc: subprocess.Popen, base: str, frames: int = 10, timeout_s: float = 300.0) -> None:
    """Wait until the server subprocess has processed ``frames`` frames (RuntimeError if it exits or is too slow)."""
    t0 = time.time()
    while True:
        if proc.poll() is not None:
            raise RuntimeError(f"server exited: {proc.stderr.read()[-2000:]}")
        try:
            if (httpx.get(f"{base}/api/status", timeout=2).json()["worker"]["frames_processed"] or 0) >= frames:
                return
        except httpx.HTTPError:
            pass
        if time.time() - t0 > timeout_s:
            raise RuntimeError(f"server did not start processing within {timeout_s:.0f} s")
        time.sleep(0.2)


def run_case(name: str, realtime: bool, seconds: float, particles: int | None, db: Path, jpeg: bool = True,
             hands: bool = False, hands_worker: str | None = None, odometry: str | None = None) -> dict:
    """One websocket run (see the module docstring); a run that fails (the server does not start processing, no
    message for 30 s) is recorded with its error instead of ending the benchmark."""
    try:
        return _run_case(name, realtime, seconds, particles, db, jpeg, hands, hands_worker, odometry)
    except (RuntimeError, TimeoutError, OSError) as exc:
        return {"case": name, "realtime": realtime, "error": f"{type(exc).__name__}: {exc}"[:300]}


def _run_case(name: str, realtime: bool, seconds: float, particles: int | None, db: Path, jpeg: bool,
              hands: bool, hands_worker: str | None, odometry: str | None = None) -> dict:
    port = free_port()
    cmd = [
        sys.executable,
        "-m",
        "app.cli",
        "serve",
        "--port",
        str(port),
        "--viser-port",
        "0",
        "--database",
        str(db),
        "--source",
        "sim:guidance-demo",
        "--mode",
        "guidance",
    ]
    if not realtime:
        cmd.append("--no-realtime")
    if particles:
        cmd += ["--particles", str(particles)]
    if hands:
        cmd.append("--hands")
    if hands_worker:
        cmd += ["--hands-worker", hands_worker]
    if odometry:
        cmd += ["--odometry", odometry]
    env = dict(os.environ, ASSEMBLY_AGENT_MAX_FPS="1000")
    if REALTIME_AHEAD:
        env["ASSEMBLY_AGENT_REALTIME_AHEAD"] = "true"
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    base = f"http://127.0.0.1:{port}"
    try:
        # with hands, past the first hand of guidance-demo (frame 39): the hand path's kernels load from numba's cache
        # on the first frame with a hand, and after a change of their source compile there (20 s of CPU)
        wait_until_processing(proc, base, frames=60 if hands else 10)
        load = os.getloadavg()[0]
        cpu0, threads0, w0 = cpu_seconds(proc.pid), cpu_by_thread(proc.pid), time.time()
        ticks0 = machine_ticks()
        sched0, children0, kernels0 = sched_by_thread(proc.pid), child_pids(proc.pid), cached_kernels()
        st0 = httpx.get(f"{base}/api/status").json()["worker"]
        msgs, n_jpeg = asyncio.run(read_ws(f"ws://127.0.0.1:{port}/ws", seconds, jpeg))
        cpu1, threads1, w1 = cpu_seconds(proc.pid), cpu_by_thread(proc.pid), time.time()
        ticks1 = machine_ticks()
        sched1, children1, kernels1 = sched_by_thread(proc.pid), child_pids(proc.pid), cached_kernels()
        st1 = httpx.get(f"{base}/api/status").json()["worker"]
        n0, n1 = st0["frames_processed"], st1["frames_processed"]
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
    lat = sorted((m["recv"] - m["wall"]) * 1000.0 for m in msgs)
    lat_proc = sorted((m["recv"] - m["wall"] - m["timings"].get("wait", 0.0)) * 1000.0 for m in msgs)
    stages: dict[str, list[float]] = {}
    for m in msgs:
        for k, v in m["timings"].items():
            stages.setdefault(k, []).append(v * 1000.0)
    tracker_ms = sorted(m["timings"]["tracker"] * 1000.0 for m in msgs if "tracker" in m["timings"])
    tracker_cpu = sorted(m["timings"]["tracker_cpu"] * 1000.0 for m in msgs if "tracker_cpu" in m["timings"])
    by_process, by_thread = cpu_split(threads0, threads1, n1 - n0)
    return {
        "case": name,
        "realtime": realtime,
        "seconds": round(w1 - w0, 2),
        "frames_processed": n1 - n0,
        "processed_fps": round((n1 - n0) / (w1 - w0), 2),
        "ws_messages": len(msgs),
        "snapshots_per_s": round(len(msgs) / (w1 - w0), 2),
        "stale_frames_dropped": st1.get("frames_dropped", 0) - st0.get("frames_dropped", 0),
        "jpeg_received_per_s": round(n_jpeg / (w1 - w0), 1),
        "latency_ms_median": round(statistics.median(lat), 1) if lat else None,
        "latency_ms_p95": round(lat[int(0.95 * (len(lat) - 1))], 1) if lat else None,
        "processing_to_ws_ms_median": round(statistics.median(lat_proc), 1) if lat_proc else None,
        "cpu_percent": round(100.0 * (cpu1 - cpu0) / (w1 - w0), 1),
        "cpu_ms_per_frame": round(1000.0 * (cpu1 - cpu0) / max(n1 - n0, 1), 1),
        "cpu_ms_per_frame_by_process": by_process,
        "cpu_ms_per_frame_by_thread": by_thread,
        "load_avg_1min": round(load, 2),
        "machine_percent": machine_split(ticks0, ticks1, cpu1 - cpu0, w1 - w0),
        "tracker_ms_median": round(statistics.median(tracker_ms), 1) if tracker_ms else None,
        "tracker_ms_p95": round(tracker_ms[int(0.95 * (len(tracker_ms) - 1))], 1) if tracker_ms else None,
        "tracker_cpu_ms_median": round(statistics.median(tracker_cpu), 1) if tracker_cpu else None,
        "stage_ms_median": {k: round(statistics.median(v), 2) for k, v in sorted(stages.items())},
        "sched_percent_by_thread": sched_split(sched0, sched1, w1 - w0),
        "frame_step": frame_steps([m["index"] for m in msgs]),
        "frame_errors": sorted({e for m in msgs for e in m["errors"]})[:5],
        "children_replaced": replaced_children(children0, children1),
        "kernels_compiled": kernels1 - kernels0,
    }


CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync"]
COUNT_PANEL_FRAMES = """() => { window.__panelFrames = 0; const el = document.getElementById('frame-index');
  new MutationObserver(() => { window.__panelFrames += 1; }).observe(el, {childList: true, characterData: true,
  subtree: true}); }"""
COUNT_ANIMATION_FRAMES = """(() => { const raf = window.requestAnimationFrame.bind(window); window.__rafs = 0;
  window.requestAnimationFrame = (cb) => raf((t) => { window.__rafs += 1; cb(t); }); })()"""


def descendants(pid: int) -> list[int]:
    """Every live descendant process of ``pid`` (from /proc)."""
    out: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            children = [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            continue
        for c in children:
            out += [c, *descendants(c)]
    return out


def own_cpu_seconds(pid: int) -> float | None:
    """User + system CPU seconds of one process (all its threads), None once it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def process_kind(pid: int, server_pid: int) -> str:
    """``server``, ``simulator`` (the server's child), ``chromium <type>`` or ``other``, from /proc/<pid>/cmdline
    (Chromium rewrites its command line into one space-separated string)."""
    if pid == server_pid:
        return "server"
    try:
        args = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace").split()
    except OSError:
        return "other"
    if args and "chrom" in Path(args[0]).name:
        kind = next((a.split("=", 1)[1] for a in args if a.startswith("--type=")), "browser")
        return f"chromium {kind}"
    if server_pid in _ancestors(pid):
        return "simulator"
    return "other"


def _ancestors(pid: int) -> list[int]:
    out = []
    while pid > 1:
        try:
            pid = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            break
        out.append(pid)
    return out


def match_priority(server_pid: int) -> int:
    """Give every thread of every Chromium process this benchmark's scheduling priority (its nice value), as the
    server has: Chromium resets its processes to nice 0 (the GPU process's main thread to -8), which on a shared
    machine run at ``nice -n -10`` would leave the browser competing with other jobs while the server does not.
    Returns the number of threads set (0 without the permission, e.g. not root with a negative nice)."""
    target, n = os.getpriority(os.PRIO_PROCESS, 0), 0
    for pid in descendants(os.getpid()):
        if not process_kind(pid, server_pid).startswith("chromium"):
            continue
        for task in Path(f"/proc/{pid}/task").glob("*"):
            try:
                os.setpriority(os.PRIO_PROCESS, int(task.name), target)
                n += 1
            except (OSError, ValueError):
                pass
    return n


def cpu_by_kind(server_pid: int) -> dict[int, tuple[str, float]]:
    """``{pid: (kind, CPU seconds)}`` of this benchmark's descendants: the server, its simulator process, the
    Playwright driver and every Chromium process."""
    out = {}
    for pid in descendants(os.getpid()):
        cpu = own_cpu_seconds(pid)
        if cpu is not None:
            out[pid] = (process_kind(pid, server_pid), cpu)
    return out


def run_browser_case(name: str, scene: bool, seconds: float, particles: int | None, db: Path) -> dict:
    """The server (realtime, viser scene on) with headless Chromium showing the panel at 127.0.0.1, with the
    embedded 3D scene (``scene``) or without it (``?scene=off``, the baseline): frames the panel shows per second
    (changes of its frame number, counted in the page), frames the server processes per second, the scene's
    redraws per second, and the CPU time of every process (server, its simulator process, each kind of Chromium
    process) over the run, per second and per frame the panel showed."""
    from playwright.sync_api import sync_playwright

    port, viser_port = free_port(), free_port()
    cmd = [sys.executable, "-m", "app.cli", "serve", "--port", str(port), "--viser-port", str(viser_port),
           "--database", str(db), "--source", "sim:guidance-demo", "--mode", "guidance"]
    if particles:
        cmd += ["--particles", str(particles)]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    base = f"http://127.0.0.1:{port}"
    chromium = os.environ.get("CHROMIUM_PATH") or "/usr/bin/chromium"
    try:
        wait_until_processing(proc, base)
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
            page = browser.new_page(viewport={"width": 1280, "height": 800})
            page.add_init_script(COUNT_ANIMATION_FRAMES)
            page.goto(base + ("/" if scene else "/?scene=off"))
            page.wait_for_function("() => /^\\d+$/.test(document.getElementById('frame-index').textContent)",
                                   timeout=60_000)
            if scene:  # the 3D scene has connected and drawn
                page.frame_locator("#viser-frame").locator("canvas").first.wait_for(timeout=60_000)
            page.wait_for_timeout(3000)  # warm-up: the scene's first geometry
            reniced = match_priority(proc.pid)
            page.evaluate(COUNT_PANEL_FRAMES)
            scene_frames = [f for f in page.frames if f != page.main_frame and f.url.startswith("http")]
            load = os.getloadavg()[0]
            draws0 = sum(f.evaluate("window.__rafs || 0") for f in scene_frames)
            st0, cpu0, w0 = httpx.get(f"{base}/api/status").json()["worker"], cpu_by_kind(proc.pid), time.time()
            page.wait_for_timeout(seconds * 1000)
            shown = page.evaluate("window.__panelFrames")
            st1, cpu1, w1 = httpx.get(f"{base}/api/status").json()["worker"], cpu_by_kind(proc.pid), time.time()
            draws1 = sum(f.evaluate("window.__rafs || 0") for f in scene_frames)
            browser.close()
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
    wall = w1 - w0
    per_kind: dict[str, float] = {}
    for pid, (kind, c1) in cpu1.items():
        per_kind[kind] = per_kind.get(kind, 0.0) + c1 - cpu0.get(pid, (kind, 0.0))[1]
    server_s = per_kind.get("server", 0.0) + per_kind.get("simulator", 0.0)
    chromium_s = sum(v for k, v in per_kind.items() if k.startswith("chromium"))
    per_frame = 1000.0 / max(shown, 1)
    return {
        "case": name,
        "scene": scene,
        "seconds": round(wall, 2),
        "load_avg_1min": round(load, 2),
        "chromium_threads_at_server_priority": reniced,
        "panel_fps": round(shown / wall, 2),
        "processed_fps": round((st1["frames_processed"] - st0["frames_processed"]) / wall, 2),
        "scene_animation_callbacks_per_s": round((draws1 - draws0) / wall, 1) if scene else None,
        "server_cpu_percent": round(100.0 * server_s / wall, 1),
        "chromium_cpu_percent": round(100.0 * chromium_s / wall, 1),
        "cpu_percent_by_process": {k: round(100.0 * v / wall, 1) for k, v in sorted(per_kind.items())},
        "server_cpu_ms_per_shown_frame": round(server_s * per_frame, 1),
        "chromium_cpu_ms_per_shown_frame": round(chromium_s * per_frame, 1),
        "cpu_ms_per_shown_frame": round((server_s + chromium_s) * per_frame, 1),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--particles", type=int, default=None, help="tracker particle count (default: the server's)")
    ap.add_argument("--no-jpeg", dest="jpeg", action="store_false", help="websocket only, no colour image fetches")
    ap.add_argument("--note", default="", help="a sentence appended to the markdown (e.g. earlier figures)")
    ap.add_argument("--stem", default="server",
                    help="results file stem (default server; another stem keeps server.md as it is, and with "
                    "--no-browser its file has no browser runs unless an earlier STEM.json had them)")
    ap.add_argument("--hands", action="store_true",
                    help="also the two websocket runs with the hand tracker on (serve --hands; issue 14's >= 28/s)")
    ap.add_argument("--hands-thread", action="store_true",
                    help="with --hands: also the two hands-on runs with the hand step in a thread of the server "
                    "(serve --hands-worker thread) instead of its child process")
    ap.add_argument("--hands-only", action="store_true",
                    help="only the two websocket runs with hands on (a quick comparison; implies --no-browser)")
    ap.add_argument("--odometry", choices=("off", "default", "fastslam", "fused"), default=None,
                    help="also the two websocket runs with this camera odometry (serve --odometry MODE) beside the "
                    "runs with the server's default")
    ap.add_argument("--realtime-ahead", action="store_true",
                    help="serve with realtime_ahead (paced frames produced ahead, handed over when due)")
    ap.add_argument("--no-browser", action="store_true",
                    help="only the websocket runs (the browser runs' figures are kept from server.json)")
    ap.add_argument("--browser-only", action="store_true",
                    help="only the server + headless browser runs (the other runs' figures are kept from server.json)")
    args = ap.parse_args()
    global REALTIME_AHEAD
    REALTIME_AHEAD = args.realtime_ahead
    if args.hands_only:
        args.hands = args.no_browser = True
    RESULTS.mkdir(parents=True, exist_ok=True)
    db = Path("/tmp") / f"bench-server-{os.getpid()}.sqlite3"
    mach = machine()
    earlier = RESULTS / f"{args.stem}.json"
    kept = json.loads(earlier.read_text()) if (args.browser_only or args.no_browser) and earlier.exists() else {}
    cases = kept.get("cases", []) if args.browser_only else [] if args.hands_only else [
        run_case("unpaced", False, args.seconds, args.particles, db, args.jpeg),
        run_case("realtime-30fps", True, args.seconds, args.particles, db, args.jpeg),
    ]
    if args.hands and not args.browser_only:
        cases += [
            run_case("unpaced, hands on", False, args.seconds, args.particles, db, args.jpeg, hands=True),
            run_case("realtime-30fps, hands on", True, args.seconds, args.particles, db, args.jpeg, hands=True),
        ]
        if args.hands_thread:
            cases += [
                run_case("unpaced, hands on, thread", False, args.seconds, args.particles, db, args.jpeg, hands=True,
                         hands_worker="thread"),
                run_case("realtime-30fps, hands on, thread", True, args.seconds, args.particles, db, args.jpeg,
                         hands=True, hands_worker="thread"),
            ]
    if args.odometry and not args.browser_only:
        cases += [
            run_case(f"unpaced, odometry {args.odometry}", False, args.seconds, args.particles, db, args.jpeg,
                     odometry=args.odometry),
            run_case(f"realtime-30fps, odometry {args.odometry}", True, args.seconds, args.particles, db, args.jpeg,
                     odometry=args.odometry),
        ]
    browser_cases = kept.get("browser_cases", []) if args.no_browser else [
        run_browser_case("panel without 3-D scene (baseline)", False, args.seconds, args.particles, db),
        run_browser_case("panel with 3-D scene", True, args.seconds, args.particles, db),
    ]
    db.unlink(missing_ok=True)
    result = {
        "benchmark": "server",
        "machine": mach,
        "scenario": "sim:guidance-demo, 5 cubes, 640x480",
        "particles": args.particles or f"{SERVER_PARTICLES} (server default)",
        "client": "websocket with each frame's JPEG (/ws?image=1)" if args.jpeg else "websocket, snapshots only",
        "realtime_ahead": REALTIME_AHEAD,
        "cases": cases,
        "cases_machine": kept.get("cases_machine", kept.get("machine")) if args.browser_only else None,
        "browser_cases": browser_cases,
        "targets": {"processed_fps": 25, "latency_ms_median": 100, "panel_fps": 25},
    }
    (RESULTS / f"{args.stem}.json").write_text(json.dumps(result, indent=2) + "\n")
    m = result["machine"]
    lines = [
        "## Web server (benchmarks/bench_server.py" + ("" if args.stem == "server" else f" --stem {args.stem}") + ")",
        "",
        f"Simulated table (guidance-demo, 5 cubes, 640×480), guidance mode, tracker preset `default` with"
        f" N = {result['particles']} particles; `assembly-agent serve` as a subprocess (simulator rendered in its"
        f" child process), one client: {result['client']}; viser scene off. Latency is measured from the frame's"
        " capture time (a paced frame's due time) to the receipt of its websocket message."
        + (" Served with `realtime_ahead` (paced frames produced ahead of their due time, handed over when due)."
           if REALTIME_AHEAD else ""),
        f"Machine: {m['nproc']} cores, {m['cpu']}, Python {m['python']}; 1-minute load average"
        f" {m['load_avg_1min']:.1f} at the start (above 1, other jobs shared the cores and the figures are"
        " pessimistic).",
        "",
        "| run | processed fps (target ≥ 25) | latency capture → ws, median / p95 ms (target < 100) | "
        "tracker ms/frame: wall median / p95, CPU median | server CPU (100 % = 1 core) | server CPU ms per frame | "
        "stale frames skipped | ws snapshots (per second) | load |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for c in cases:
        if "error" in c:
            lines.append(f"| {c['case']} | failed: {c['error']} | | | | | | | |")
            continue
        lines.append(
            f"| {c['case']} | {c['processed_fps']} | {c['latency_ms_median']} / {c['latency_ms_p95']} | "
            f"{c['tracker_ms_median']} / {c['tracker_ms_p95']}, {c['tracker_cpu_ms_median']} | {c['cpu_percent']} % | "
            f"{c.get('cpu_ms_per_frame', '–')} | {c['stale_frames_dropped']} | {c['ws_messages']} of "
            f"{c['frames_processed']} frames ({c.get('snapshots_per_s', '–')}/s) | {c.get('load_avg_1min', '–')} |"
        )
    lines += ["", "Server CPU = the server process, its simulator process and its hand process (with hands on, worker "
              "\"process\"); CPU ms per frame = that CPU time over the frames processed; load = the machine's 1-minute "
              "load average when the run's measurement started (above 1, other jobs shared the 2 cores). Scheduler "
              "states (from /proc/…/schedstat): a thread that waits for a core is starved of CPU (other threads or "
              "jobs hold the cores); one that is blocked waits for a lock, a queue, a pipe or a timer."]
    for c in cases:
        problems = [*c.get("frame_errors", [])] + [f"the {p} process ended during the run (replaced)"
                                                  for p in c.get("children_replaced", [])]
        if c.get("kernels_compiled"):
            problems.append(f"{c['kernels_compiled']} files of compiled kernels written to numba's cache during the "
                            "run (a cold cache after a kernel change: run the benchmark again)")
        if "error" not in c and problems:
            lines += ["", f"**Not a steady run** ({c['case']}): " + "; ".join(problems)]
    for c in cases:
        if "error" in c or "cpu_ms_per_frame_by_thread" not in c:
            continue
        lines += ["", f"CPU ms per frame by process and thread ({c['case']} run): " + "; ".join(
            f"{k} {v}" for k, v in c["cpu_ms_per_frame_by_thread"].items())]
    for c in cases:
        mp = c.get("machine_percent")
        if "error" in c or not mp:
            continue
        lines += ["", f"The machine's cores during the {c['case']} run (% of one core): busy {mp['busy']}, of which"
                  f" other jobs than the server {mp['other_jobs']}; taken by the host (steal) {mp['steal']}."]
    for c in cases:
        sched = {k: v for k, v in c.get("sched_percent_by_thread", {}).items() if k in SCHED_THREADS}
        if "error" in c or not sched:
            continue
        step = c.get("frame_step") or {}
        lines += ["", f"Scheduler states, % of the wall time on a core / waiting for a core / blocked ({c['case']} "
                  "run): " + "; ".join(f"{k} {v['run']} / {v['runqueue']} / {v['blocked']}" for k, v in sched.items())
                  + (f"; frames advanced per snapshot {step['mean']} (at most {step['max']})" if step else "")]
    for c in cases:
        if "error" in c:
            continue
        lines += [
            "",
            f"Median time per stage (ms, {c['case']} run): "
            + ", ".join(f"{k} {v}" for k, v in c["stage_ms_median"].items()),
        ]
    if args.no_browser and browser_cases:
        lines += ["", "The browser runs below are kept from an earlier run (`--no-browser` re-measured only the "
                  "websocket runs above)."]
    if result["cases_machine"]:
        lines += ["", "The runs above are kept from an earlier run (`--browser-only` re-measured only the browser"
                  f" runs below); its 1-minute load average was {result['cases_machine']['load_avg_1min']:.1f}."]
    if browser_cases:
        lines += _browser_lines(browser_cases)
    if args.note:
        lines += ["", args.note]
    lines.append("")
    (RESULTS / f"{args.stem}.md").write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


def _browser_lines(browser_cases: list[dict]) -> list[str]:
    """The markdown of the server + headless browser runs (table and CPU by process)."""
    base_fps = browser_cases[0]["panel_fps"]
    lines = [
        "",
        "Server and a headless Chromium (Debian's, software WebGL: SwiftShader) on the same machine, the panel open at"
        " http://127.0.0.1 in a 1280×800 window (realtime source, viser scene on in the server): frames the panel"
        " shows per second (its frame number changes, counted in the page), frames the server processes, the 3-D"
        " scene page's animation-frame callbacks per second (its redraws and other animations), and CPU time over"
        " the run (100 % = one core) of the server with its simulator"
        " process and of all Chromium processes, also per frame the panel showed; the baseline is the same panel"
        " without the embedded 3-D scene (`?scene=off`). 1-minute load average at the start of each run. Every"
        " Chromium thread runs at the server's priority (the benchmark's nice value; Chromium would reset its"
        " renderers to 0).",
        "",
        "| run | panel fps (target ≥ 25) | ratio to the baseline | server processed fps | scene animation-frame "
        "callbacks/s | server + simulator CPU | Chromium CPU | CPU ms per shown frame: server / Chromium / total "
        "| load |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for c in browser_cases:
        ratio = c["panel_fps"] / base_fps if base_fps else float("nan")
        redraws = "–" if c["scene_animation_callbacks_per_s"] is None else c["scene_animation_callbacks_per_s"]
        lines.append(
            f"| {c['case']} | {c['panel_fps']} | {ratio:.2f} | {c['processed_fps']} | {redraws} | "
            f"{c['server_cpu_percent']} % | {c['chromium_cpu_percent']} % | {c['server_cpu_ms_per_shown_frame']} / "
            f"{c['chromium_cpu_ms_per_shown_frame']} / {c['cpu_ms_per_shown_frame']} | {c['load_avg_1min']:.1f} |"
        )
    lines += ["", "CPU by process (% of one core): " + "; ".join(
        f"{c['case']}: " + ", ".join(f"{k} {v}" for k, v in c["cpu_percent_by_process"].items() if v >= 0.5)
        for c in browser_cases)]
    return lines


if __name__ == "__main__":
    sys.exit(main())
