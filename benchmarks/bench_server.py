"""Benchmark of the web server: processed frames per second, frame → websocket latency, server CPU use.

Runs ``assembly-agent serve`` as a subprocess on the simulated table (scenario guidance-demo, 5 cubes,
640×480, guidance mode, the server's default settings: tracker preset ``default`` with N = 100 particles,
simulator rendered in a child process) with one client (this script) doing what the browser panel does:
reading every ``/ws`` message and fetching ``/api/frame.jpg`` at up to 15 Hz (``--no-jpeg``: websocket
only). Two runs: *unpaced* (``--no-realtime``: frames as fast as the pipeline takes them → throughput)
and *realtime* (the simulator at 30 fps, what a user sees; stale frames are skipped). Latency = time the
websocket message is received − the snapshot's ``wall_time``, the frame's capture time (a paced frame's
due time; an unpaced frame's start of rendering); both clocks are this machine's. CPU = user+system CPU
time of the server process and its children (the simulator's process) / wall time (100 % = one core),
from /proc. The tracker's own time per frame comes from the snapshots' ``timings``.

Writes benchmarks/results/server.json and server.md.

    .venv/bin/python benchmarks/bench_server.py [--seconds 20] [--particles N]
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


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a process (its threads) and its live child processes, from /proc."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    ticks = os.sysconf("SC_CLK_TCK")
    total = (int(fields[11]) + int(fields[12])) / ticks
    children: set[int] = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            children.update(int(c) for c in (task / "children").read_text().split())
        except OSError:
            pass
    return total + sum(cpu_seconds(c) for c in children)


def machine() -> dict:
    return machine_info()


async def fetch_jpegs(base: str, until: float, hz: float = 15.0) -> int:
    """Fetch the colour image like the panel does (one request at a time, at most ``hz`` per second)."""
    n = 0
    async with httpx.AsyncClient(timeout=10) as client:
        while time.time() < until:
            t0 = time.time()
            r = await client.get(f"{base}/api/frame.jpg")
            n += r.status_code == 200
            await asyncio.sleep(max(0.0, 1.0 / hz - (time.time() - t0)))
    return n


async def read_ws(url: str, seconds: float, base: str | None) -> tuple[list[dict], int]:
    import websockets

    out = []
    t_end = time.time() + seconds
    jpegs = asyncio.create_task(fetch_jpegs(base, t_end)) if base else None
    async with websockets.connect(url, max_size=None) as ws:
        while time.time() < t_end:
            msg = await asyncio.wait_for(ws.recv(), timeout=30)
            now = time.time()
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
    return out, (await jpegs if jpegs else 0)


def wait_until_processing(proc: subprocess.Popen, base: str, frames: int = 10, timeout_s: float = 120.0) -> None:
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


def run_case(name: str, realtime: bool, seconds: float, particles: int | None, db: Path, jpeg: bool = True) -> dict:
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
    env = dict(os.environ, ASSEMBLY_AGENT_MAX_FPS="1000")
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    base = f"http://127.0.0.1:{port}"
    try:
        wait_until_processing(proc, base)
        cpu0, w0 = cpu_seconds(proc.pid), time.time()
        st0 = httpx.get(f"{base}/api/status").json()["worker"]
        msgs, n_jpeg = asyncio.run(read_ws(f"ws://127.0.0.1:{port}/ws", seconds, base if jpeg else None))
        cpu1, w1 = cpu_seconds(proc.pid), time.time()
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
    return {
        "case": name,
        "realtime": realtime,
        "seconds": round(w1 - w0, 2),
        "frames_processed": n1 - n0,
        "processed_fps": round((n1 - n0) / (w1 - w0), 2),
        "ws_messages": len(msgs),
        "stale_frames_dropped": st1.get("frames_dropped", 0) - st0.get("frames_dropped", 0),
        "jpeg_fetched_per_s": round(n_jpeg / (w1 - w0), 1),
        "latency_ms_median": round(statistics.median(lat), 1) if lat else None,
        "latency_ms_p95": round(lat[int(0.95 * (len(lat) - 1))], 1) if lat else None,
        "processing_to_ws_ms_median": round(statistics.median(lat_proc), 1) if lat_proc else None,
        "cpu_percent": round(100.0 * (cpu1 - cpu0) / (w1 - w0), 1),
        "tracker_ms_median": round(statistics.median(tracker_ms), 1) if tracker_ms else None,
        "tracker_ms_p95": round(tracker_ms[int(0.95 * (len(tracker_ms) - 1))], 1) if tracker_ms else None,
        "tracker_cpu_ms_median": round(statistics.median(tracker_cpu), 1) if tracker_cpu else None,
        "stage_ms_median": {k: round(statistics.median(v), 2) for k, v in sorted(stages.items())},
        "frame_errors": sorted({e for m in msgs for e in m["errors"]})[:5],
    }


CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync"]
COUNT_PANEL_FRAMES = """() => { window.__panelFrames = 0; const el = document.getElementById('frame-index');
  new MutationObserver(() => { window.__panelFrames += 1; }).observe(el, {childList: true, characterData: true,
  subtree: true}); }"""


def run_browser_case(name: str, scene: bool, seconds: float, particles: int | None, db: Path) -> dict:
    """The server (realtime, viser scene on) with headless Chromium showing the panel, with the embedded 3D
    scene (``scene``) or without it (``?scene=off``, the baseline): frames the panel shows per second (changes
    of its frame number, counted in the page) and frames the server processes per second."""
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
            page.goto(base + ("/" if scene else "/?scene=off"))
            page.wait_for_function("() => /^\\d+$/.test(document.getElementById('frame-index').textContent)",
                                   timeout=60_000)
            if scene:  # the 3D scene has connected and drawn
                page.frame_locator("#viser-frame").locator("canvas").first.wait_for(timeout=60_000)
            page.wait_for_timeout(3000)  # warm-up: the scene's first geometry
            page.evaluate(COUNT_PANEL_FRAMES)
            st0, cpu0, w0 = httpx.get(f"{base}/api/status").json()["worker"], cpu_seconds(proc.pid), time.time()
            page.wait_for_timeout(seconds * 1000)
            shown = page.evaluate("window.__panelFrames")
            st1, cpu1, w1 = httpx.get(f"{base}/api/status").json()["worker"], cpu_seconds(proc.pid), time.time()
            browser.close()
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
    return {
        "case": name,
        "scene": scene,
        "seconds": round(w1 - w0, 2),
        "panel_fps": round(shown / (w1 - w0), 2),
        "processed_fps": round((st1["frames_processed"] - st0["frames_processed"]) / (w1 - w0), 2),
        "server_cpu_percent": round(100.0 * (cpu1 - cpu0) / (w1 - w0), 1),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--particles", type=int, default=None, help="tracker particle count (default: the server's)")
    ap.add_argument("--no-jpeg", dest="jpeg", action="store_false", help="websocket only, no colour image fetches")
    ap.add_argument("--note", default="", help="a sentence appended to the markdown (e.g. earlier figures)")
    ap.add_argument("--browser-only", action="store_true",
                    help="only the server + headless browser runs (the other runs' figures are kept from server.json)")
    args = ap.parse_args()
    RESULTS.mkdir(parents=True, exist_ok=True)
    db = Path("/tmp") / f"bench-server-{os.getpid()}.sqlite3"
    mach = machine()
    earlier = RESULTS / "server.json"
    kept = json.loads(earlier.read_text()) if args.browser_only and earlier.exists() else {}
    cases = kept.get("cases", []) if args.browser_only else [
        run_case("unpaced", False, args.seconds, args.particles, db, args.jpeg),
        run_case("realtime-30fps", True, args.seconds, args.particles, db, args.jpeg),
    ]
    browser_cases = [
        run_browser_case("panel without 3-D scene (baseline)", False, args.seconds, args.particles, db),
        run_browser_case("panel with 3-D scene", True, args.seconds, args.particles, db),
    ]
    db.unlink(missing_ok=True)
    result = {
        "benchmark": "server",
        "machine": mach,
        "scenario": "sim:guidance-demo, 5 cubes, 640x480",
        "particles": args.particles or f"{SERVER_PARTICLES} (server default)",
        "client": "websocket + colour image at ≤ 15 Hz" if args.jpeg else "websocket only",
        "cases": cases,
        "cases_machine": kept.get("cases_machine", kept.get("machine")) if args.browser_only else None,
        "browser_cases": browser_cases,
        "targets": {"processed_fps": 25, "latency_ms_median": 100, "panel_fps": 25},
    }
    (RESULTS / "server.json").write_text(json.dumps(result, indent=2) + "\n")
    m = result["machine"]
    lines = [
        "## Web server (benchmarks/bench_server.py)",
        "",
        f"Simulated table (guidance-demo, 5 cubes, 640×480), guidance mode, tracker preset `default` with"
        f" N = {result['particles']} particles; `assembly-agent serve` as a subprocess (simulator rendered in its"
        f" child process), one client: {result['client']}; viser scene off. Latency is measured from the frame's"
        " capture time (a paced frame's due time) to the receipt of its websocket message.",
        f"Machine: {m['nproc']} cores, {m['cpu']}, Python {m['python']}; 1-minute load average"
        f" {m['load_avg_1min']:.1f} at the start (above 1, other jobs shared the cores and the figures are"
        " pessimistic).",
        "",
        "| run | processed fps (target ≥ 25) | latency capture → ws, median / p95 ms (target < 100) | "
        "tracker ms/frame: wall median / p95, CPU median | server CPU (100 % = 1 core) | stale frames skipped | "
        "ws messages |",
        "|---|---|---|---|---|---|---|",
    ]
    for c in cases:
        lines.append(
            f"| {c['case']} | {c['processed_fps']} | {c['latency_ms_median']} / {c['latency_ms_p95']} | "
            f"{c['tracker_ms_median']} / {c['tracker_ms_p95']}, {c['tracker_cpu_ms_median']} | {c['cpu_percent']} % | "
            f"{c['stale_frames_dropped']} | {c['ws_messages']} of {c['frames_processed']} frames |"
        )
    for c in cases:
        lines += [
            "",
            f"Median time per stage (ms, {c['case']} run): "
            + ", ".join(f"{k} {v}" for k, v in c["stage_ms_median"].items()),
        ]
    if result["cases_machine"]:
        lines += ["", "The runs above are kept from an earlier run (`--browser-only` re-measured only the browser"
                  f" runs below); its 1-minute load average was {result['cases_machine']['load_avg_1min']:.1f}."]
    base_fps = browser_cases[0]["panel_fps"]
    lines += [
        "",
        "Server and a headless Chromium (Debian's, software WebGL) on the same machine, the panel open at 1280×800"
        " (realtime source, viser scene on in the server): frames the panel shows per second (its frame number"
        " changes, counted in the page) and frames the server processes; the baseline is the same panel without"
        " the embedded 3-D scene (`?scene=off`).",
        "",
        "| run | panel fps (target ≥ 25) | ratio to the baseline | server processed fps | server CPU |",
        "|---|---|---|---|---|",
    ]
    for c in browser_cases:
        ratio = c["panel_fps"] / base_fps if base_fps else float("nan")
        lines.append(f"| {c['case']} | {c['panel_fps']} | {ratio:.2f} | {c['processed_fps']} | "
                     f"{c['server_cpu_percent']} % |")
    if args.note:
        lines += ["", args.note]
    lines.append("")
    (RESULTS / "server.md").write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
