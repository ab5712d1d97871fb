"""Soak benchmark of the web server under hostile load: memory (RSS) and stream rate over time.

Runs ``assembly-agent serve`` as a subprocess with its default settings (simulated table guidance-demo in real
time, 30 fps, guidance mode, N = 100 particles, simulator in a child process, viser off) and keeps it busy for
``--minutes`` (the full soak is 60 min; not part of the tests):

* ``--viewers`` websocket clients reading every snapshot, one client fetching the colour image at 15 Hz
  (what the panel does), the whole time;
* after a quiet first part (``--quiet-fraction`` of the run: the baseline of the same server on the same
  stream without hostile traffic), a hostile mix at ``--hostile-hz`` requests per second from one address:
  wrong teacher passwords, path traversal in a task reference, out-of-range ids, ``Infinity`` in a box, 1 MB
  bodies, a 20 MB body, source switches without login, a foreign Host header, a foreign Origin on ``/ws``,
  GET floods — and a logged-in teacher creating, editing and deleting tasks.

Every ``--interval`` seconds it records the server's RSS (the process and its children, from /proc), the
processed frame rate (``/api/status``), websocket snapshots per second per viewer (the slowest viewer and
the median) and the answers by status code. Reported: per-phase medians, the ratio hostile / quiet, the RSS
slope over the hostile part (MiB per hour, least squares), and any 5xx answer (there should be none).

Writes benchmarks/results/soak.json and soak.md (``--name NAME``: NAME.json and NAME.md).

    .venv/bin/python benchmarks/bench_soak.py [--minutes 60] [--viewers 10] [--interval 10]
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from bench_server import free_port  # noqa: E402 - benchmarks/ is this script's folder

from tracker.evaluation.machine_info import machine_info  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
PASSWORD = "soak-benchmark-teacher"
TASK = {"source_sentence": "Μου αρέσει ο καφές", "words": ["Me", "gusta", "el", "café"]}


def rss_mib(pid: int) -> float:
    """Resident memory of a process and its live descendants, MiB (VmRSS from /proc)."""
    total = 0.0
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                total += int(line.split()[1]) / 1024.0
    except OSError:
        return 0.0
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            children = [int(c) for c in (task / "children").read_text().split()]
        except OSError:
            continue
        total += sum(rss_mib(c) for c in children)
    return total


def slope_per_hour(ts: list[float], ys: list[float]) -> float | None:
    """Least-squares slope of ``ys`` over ``ts`` (seconds), per hour."""
    if len(ts) < 3:
        return None
    mt, my = statistics.fmean(ts), statistics.fmean(ys)
    den = sum((t - mt) ** 2 for t in ts)
    return None if den == 0 else 3600.0 * sum((t - mt) * (y - my) for t, y in zip(ts, ys, strict=True)) / den


class Load:
    """Counters shared by the clients."""

    def __init__(self, viewers: int) -> None:
        self.ws_msgs = [0] * viewers
        self.codes: collections.Counter[str] = collections.Counter()
        self.hostile = False
        self.stop = False


async def viewer(url: str, load: Load, i: int) -> None:
    import websockets

    while not load.stop:
        try:
            async with websockets.connect(url, max_size=None) as ws:
                while not load.stop:
                    await asyncio.wait_for(ws.recv(), timeout=30)
                    load.ws_msgs[i] += 1
        except Exception:  # noqa: BLE001 - a dropped viewer reconnects (counted as a gap in its rate)
            load.codes["ws-reconnect"] += 1
            await asyncio.sleep(0.5)


async def jpeg_client(base: str, load: Load, hz: float = 15.0) -> None:
    async with httpx.AsyncClient(timeout=10) as client:
        while not load.stop:
            t0 = time.time()
            try:
                r = await client.get(f"{base}/api/frame.jpg")
                load.codes[f"jpeg {r.status_code}"] += 1
            except httpx.HTTPError:
                load.codes["jpeg error"] += 1
            await asyncio.sleep(max(0.0, 1.0 / hz - (time.time() - t0)))


def hostile_requests(base: str) -> list[tuple[str, dict]]:
    """(label, httpx request arguments) of the hostile mix, used in turn."""
    json_h = {"content-type": "application/json"}
    return [
        ("wrong-login", {"method": "POST", "url": "/api/auth/login", "json": {"password": "guess-guess-guess"}}),
        ("traversal", {"method": "POST", "url": "/api/modes", "json": {"mode": "guidance", "task": "../../etc/x"}}),
        ("huge-id", {"method": "GET", "url": "/api/tasks/9223372036854775808"}),
        (
            "inf-box",
            {"method": "POST", "url": "/api/boxes", "content": '{"x":Infinity,"y":1,"w":5,"h":5}', "headers": json_h},
        ),
        ("1MB-body", {"method": "POST", "url": "/api/modes", "content": b"x" * 1_000_000, "headers": json_h}),
        ("source-no-login", {"method": "POST", "url": "/api/sources", "json": {"source": "recording:/etc"}}),
        ("foreign-host", {"method": "GET", "url": "/api/status", "headers": {"host": "evil.example"}}),
        ("get-flood", {"method": "GET", "url": "/api/tasks"}),
        ("get-flood", {"method": "GET", "url": "/api/status"}),
    ]


async def hostile_client(base: str, port: int, load: Load, hz: float) -> None:
    import websockets

    reqs = hostile_requests(base)
    async with (
        httpx.AsyncClient(base_url=base, timeout=30) as client,
        httpx.AsyncClient(base_url=base, timeout=30) as teacher,
    ):
        r = await teacher.post("/api/auth/login", json={"password": PASSWORD})
        load.codes[f"teacher-login {r.status_code}"] += 1
        k = 0
        while not load.stop:
            if not load.hostile:
                await asyncio.sleep(0.2)
                continue
            t0 = time.time()
            label, req = reqs[k % len(reqs)]
            try:
                r = await client.request(**req)
                load.codes[f"{label} {r.status_code}"] += 1
                if k % 10 == 0:  # a teacher edits tasks now and then (and sends a bad sentence)
                    r = await teacher.post("/api/tasks", json={"source_sentence": "\x00", "words": ["a", "b"]})
                    load.codes[f"teacher-bad-sentence {r.status_code}"] += 1
                    r = await teacher.post("/api/tasks", json=TASK)
                    load.codes[f"teacher-create {r.status_code}"] += 1
                    if r.status_code == 201:
                        tid = r.json()["id"]
                        r = await teacher.put(
                            f"/api/tasks/{tid}", json={**TASK, "words": ["gusta", "Me", "el", "café"]}
                        )
                        load.codes[f"teacher-edit {r.status_code}"] += 1
                        r = await teacher.delete(f"/api/tasks/{tid}")
                        load.codes[f"teacher-delete {r.status_code}"] += 1
                if k % 50 == 0:
                    r = await client.post(
                        "/api/modes", content=b"y" * 20_000_000, headers={"content-type": "text/plain"}
                    )
                    load.codes[f"20MB-body {r.status_code}"] += 1
                    try:
                        async with websockets.connect(
                            f"ws://127.0.0.1:{port}/ws", additional_headers={"Origin": "http://evil.example"}
                        ) as ws:
                            await ws.recv()
                            load.codes["foreign-origin-ws accepted"] += 1
                    except Exception:  # noqa: BLE001 - refused, as it should be
                        load.codes["foreign-origin-ws refused"] += 1
            except httpx.HTTPError as exc:
                load.codes[f"{label} {type(exc).__name__}"] += 1
            k += 1
            await asyncio.sleep(max(0.0, 1.0 / hz - (time.time() - t0)))


async def sampler(base: str, pid: int, load: Load, seconds: float, interval: float, quiet_s: float) -> list[dict]:
    samples: list[dict] = []
    t_start = time.time()
    async with httpx.AsyncClient(timeout=30) as client:
        st = (await client.get(f"{base}/api/status")).json()["worker"]
        prev_t, prev_frames, prev_msgs = time.time(), st["frames_processed"], list(load.ws_msgs)
        while time.time() - t_start < seconds:
            load.hostile = time.time() - t_start >= quiet_s
            await asyncio.sleep(interval)
            st = (await client.get(f"{base}/api/status")).json()["worker"]
            now, msgs = time.time(), list(load.ws_msgs)
            dt = now - prev_t
            rates = sorted((b - a) / dt for a, b in zip(prev_msgs, msgs, strict=True))
            samples.append(
                {
                    "t_s": round(now - t_start, 1),
                    "phase": "hostile" if load.hostile else "quiet",
                    "rss_mib": round(rss_mib(pid), 1),
                    "processed_fps": round((st["frames_processed"] - prev_frames) / dt, 2),
                    "ws_per_viewer_min": round(rates[0], 2),
                    "ws_per_viewer_median": round(statistics.median(rates), 2),
                }
            )
            print(json.dumps(samples[-1]), flush=True)
            prev_t, prev_frames, prev_msgs = now, st["frames_processed"], msgs
    load.stop = True
    return samples


async def run_load(base: str, port: int, pid: int, args) -> tuple[list[dict], dict]:
    load = Load(args.viewers)
    seconds = args.minutes * 60.0
    tasks = [asyncio.create_task(viewer(f"ws://127.0.0.1:{port}/ws", load, i)) for i in range(args.viewers)]
    tasks.append(asyncio.create_task(jpeg_client(base, load)))
    tasks.append(asyncio.create_task(hostile_client(base, port, load, args.hostile_hz)))
    samples = await sampler(base, pid, load, seconds, args.interval, seconds * args.quiet_fraction)
    for t in tasks:
        t.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    return samples, dict(sorted(load.codes.items()))


def summarize(samples: list[dict]) -> dict:
    out = {}
    for phase in ("quiet", "hostile"):
        ss = [s for s in samples if s["phase"] == phase]
        if not ss:
            continue
        out[phase] = {
            "samples": len(ss),
            "processed_fps_median": round(statistics.median(s["processed_fps"] for s in ss), 2),
            "processed_fps_min": min(s["processed_fps"] for s in ss),
            "ws_per_viewer_min": min(s["ws_per_viewer_min"] for s in ss),
            "ws_per_viewer_median": round(statistics.median(s["ws_per_viewer_median"] for s in ss), 2),
            "rss_mib_first": ss[0]["rss_mib"],
            "rss_mib_last": ss[-1]["rss_mib"],
            "rss_mib_max": max(s["rss_mib"] for s in ss),
            "rss_slope_mib_per_h": round(slope_per_hour([s["t_s"] for s in ss], [s["rss_mib"] for s in ss]) or 0.0, 1),
        }
    if "quiet" in out and "hostile" in out and out["quiet"]["processed_fps_median"]:
        out["fps_ratio_hostile_over_quiet"] = round(
            out["hostile"]["processed_fps_median"] / out["quiet"]["processed_fps_median"], 3
        )
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=60.0, help="length of the run (the full soak: 60)")
    ap.add_argument("--viewers", type=int, default=10)
    ap.add_argument("--interval", type=float, default=10.0, help="seconds between samples")
    ap.add_argument("--hostile-hz", type=float, default=20.0, help="hostile requests per second")
    ap.add_argument("--quiet-fraction", type=float, default=1 / 6, help="first part of the run without hostiles")
    ap.add_argument("--note", default="", help="a sentence appended to the markdown")
    ap.add_argument("--name", default="soak", help="result files benchmarks/results/NAME.json and NAME.md (default "
                    "soak; e.g. soak_short for a short run that keeps the full soak's figures)")
    args = ap.parse_args()
    if not args.name.replace("_", "").isalnum():
        ap.error("--name: letters, digits and underscores only")
    RESULTS.mkdir(parents=True, exist_ok=True)
    mach = machine_info()
    db = Path("/tmp") / f"bench-soak-{os.getpid()}.sqlite3"
    port = free_port()
    cmd = [sys.executable, "-m", "app.cli", "serve", "--port", str(port), "--viser-port", "0", "--database", str(db)]
    env = dict(os.environ, ASSEMBLY_AGENT_TEACHER_PASSWORD=PASSWORD)
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    base = f"http://127.0.0.1:{port}"
    try:
        t0 = time.time()
        while True:
            if proc.poll() is not None:
                raise RuntimeError(f"server exited: {proc.stderr.read()[-2000:]}")
            try:
                if (httpx.get(f"{base}/api/status", timeout=2).json()["worker"]["frames_processed"] or 0) >= 30:
                    break
            except httpx.HTTPError:
                pass
            if time.time() - t0 > 120:
                raise RuntimeError("server did not start processing within 120 s")
            time.sleep(0.5)
        samples, codes = asyncio.run(run_load(base, port, proc.pid, args))
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
        for f in db.parent.glob(db.name + "*"):
            f.unlink(missing_ok=True)
    summary = summarize(samples)
    server_errors = {k: v for k, v in codes.items() if k.split()[-1].startswith("5")}
    result = {
        "benchmark": "soak",
        "machine": mach,
        "minutes": args.minutes,
        "viewers": args.viewers,
        "hostile_hz": args.hostile_hz,
        "summary": summary,
        "server_errors_5xx": server_errors,
        "answers": codes,
        "samples": samples,
    }
    (RESULTS / f"{args.name}.json").write_text(json.dumps(result, indent=2, ensure_ascii=False) + "\n")
    m = mach
    q, h = summary.get("quiet", {}), summary.get("hostile", {})
    lines = [
        "## Soak under hostile load (benchmarks/bench_soak.py)"
        + ("" if args.name == "soak" else f" — {args.minutes:g}-minute run (`--name {args.name}`)"),
        "",
        f"`assembly-agent serve` with its defaults (sim:guidance-demo in real time at 30 fps, guidance mode, N = 100,"
        f" viser off) for {args.minutes:g} min: {args.viewers} websocket viewers and a 15 Hz colour-image client"
        f" throughout; after a quiet {args.quiet_fraction * 100:.0f} % (the baseline: same server, same stream, no"
        f" hostile traffic) a hostile mix at {args.hostile_hz:g} requests/s from one address (wrong passwords, path"
        " traversal, huge ids, Infinity, 1 MB and 20 MB bodies, source switch without login, foreign Host and Origin,"
        " GET floods) plus a logged-in teacher creating/editing/deleting tasks. The full soak is 60 min"
        " (`--minutes 60`); the figures below are from the run stated here.",
        f"Machine: {m['nproc']} cores, {m['cpu']}, Python {m['python']}; 1-minute load average"
        f" {m['load_avg_1min']:.1f} at the start (above 1: other jobs shared the cores, the figures are pessimistic).",
        "",
        "| phase | samples | processed fps median / min | ws snapshots/s per viewer: slowest / median |"
        " RSS MiB first → last (max) |",
        "|---|---|---|---|---|",
    ]
    for name, p in (("quiet (baseline)", q), ("hostile", h)):
        if p:
            lines.append(
                f"| {name} | {p['samples']} | {p['processed_fps_median']} / {p['processed_fps_min']} | "
                f"{p['ws_per_viewer_min']} / {p['ws_per_viewer_median']} | {p['rss_mib_first']} → {p['rss_mib_last']}"
                f" ({p['rss_mib_max']}) |"
            )
    lines += [
        "",
        f"Ratio hostile / quiet processed fps: {summary.get('fps_ratio_hostile_over_quiet')}; RSS slope (least"
        f" squares, MiB/h): quiet {q.get('rss_slope_mib_per_h')}, hostile {h.get('rss_slope_mib_per_h')} (a short run"
        f" overstates it: the first minutes include warm-up); 5xx answers: {sum(server_errors.values())}.",
        "",
        "Answers by kind: " + ", ".join(f"{k}: {v}" for k, v in codes.items()),
        "",
        "RSS and rate over time (t s: RSS MiB, processed fps, slowest viewer ws/s): "
        + "; ".join(f"{s['t_s']:.0f}: {s['rss_mib']}, {s['processed_fps']}, {s['ws_per_viewer_min']}" for s in samples),
    ]
    if args.note:
        lines += ["", args.note]
    lines.append("")
    (RESULTS / f"{args.name}.md").write_text("\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
