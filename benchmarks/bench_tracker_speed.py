"""Speed of the tracker on one core (issue 11, item 6): held-out simulator sessions, decoding and perception included.

Sessions of the held-out design (:data:`benchmarks.bench_heldout.DESIGN`, seeds >= 100 as that benchmark gives
them: session k gets seed 100 + k): two 5-cube ones (default sessions 0 and 1, ``static`` with a fixed and with a
hand-held camera: the camera odometry idles on a fixed camera and works every frame on a moving one) and a 7-cube
one (default session 15, ``learning-5``, swaying camera). Each session is rendered by the simulator, written as a
recording (PNG colour, 16-bit PNG depth in millimetres, as ``assembly-agent simulate`` writes it) and then read
back and tracked frame by frame exactly as ``assembly-agent track`` does it
(:class:`app.commands.track.TrackSession`: table plane followed, colour detection, one tracker step; default
preset, N = 225). Per frame, thread CPU time (``time.thread_time``; OpenCV, numba and BLAS held to one thread) of

* **decode**: reading the frame's colour and depth images (:meth:`RecordingSource.read`; the PNGs by
  :mod:`tracker.sources.png_decode`); beside it, **decode (OpenCV)**: the same two files read the way the reader did
  before that decoder (``cv2.imdecode``, BGR → RGB, the depth units → metres table), same pixels, as the baseline;
* **perception**: the table plane, the colour detection and the camera odometry (``TrackSession.step`` minus the
  tracker step; the odometry is ``track``'s default, ``fused``, unless ``--odometry`` says otherwise; its own share
  is reported as **odometry**);
* **tracker**: the tracker step (prediction, passes, refinement, recovery);
* **pipeline**: the three together, and the frames per second one core would give (1000 / pipeline ms).

Beside it, on the same frames in the same run, the baseline: frame-to-frame point-to-plane ICP per part
(:class:`benchmarks.icp_baseline.ICPTracker`, Open3D when installed — ``pip install -e .[bench]`` — else its
numpy/scipy fallback, named in the report), table points removed with our plane; its CPU time per frame and the
ratio ours / ICP. Figures are medians (and means) over the frames after the first three (the first frames hold
numba's compilation or cache loading). Issue 11's targets: 5 cubes >= 30 fps including decoding and perception;
7 cubes <= 15 ms tracker time per frame.

Writes benchmarks/results/tracker_speed.json and .md. Usage::

    .venv/bin/python benchmarks/bench_tracker_speed.py [--frames 150] [--sessions 1,15] [--no-write]
        [--pair quiet_skip=true] [--odometry off|default|fused]
    .venv/bin/python benchmarks/bench_tracker_speed.py --dev [--seeds 0,1,2,3,4] --sessions 15 --pair KEY=VALUE

``--dev``: the same sessions on the tuning seeds (session k gets ``seeds[k mod count]``, seeds 0-4 by default), for
deciding a speed setting by ``--pair``; prints only (never written into benchmarks/results, so never into
BENCHMARKS.md).
"""

from __future__ import annotations

import os

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.bench_heldout import DESIGN  # noqa: E402
from benchmarks.result_files import git_commit, rewrite_markdown, write_results  # noqa: E402
from tracker.evaluation.machine_info import machine_info  # noqa: E402
from tracker.evaluation.seeds import check_seeds  # noqa: E402

TARGET_FPS_5 = 30.0
"""Issue 11: 5 cubes, N = 225, at least this many frames per second including decoding and perception."""
TARGET_TRACKER_MS_7 = 15.0
"""Issue 11: 7 cubes, N = 225, at most this tracker time per frame (ms)."""
STAGES = ("decode", "perception", "odometry", "tracker", "pipeline", "icp", "decode_opencv")


def _stats(values: list[float]) -> dict:
    v = np.asarray(values[3:] or values, np.float64)
    return {"median": round(float(np.median(v)), 2), "mean": round(float(np.mean(v)), 2),
            "p95": round(float(np.percentile(v, 95)), 2)}


def parse_overrides(text: str) -> dict:
    """``KEY=VALUE[,KEY=VALUE…]`` → TrackerConfig overrides (values read as JSON, else kept as strings)."""
    import json

    out = {}
    for item in (s for s in text.split(",") if s.strip()):
        if "=" not in item:
            raise ValueError(f"--pair expects KEY=VALUE pairs, got {item!r}")
        key, value = (x.strip() for x in item.split("=", 1))
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def _decode_opencv(rec, position: int) -> tuple:
    """A recording frame's colour and depth read as :class:`RecordingSource` read them before
    :mod:`tracker.sources.png_decode` (``cv2.imdecode``; the decode baseline, same pixels)."""
    import cv2

    from tracker.sources.recording import depth_units_to_metres

    e = rec._entries[position]
    bgr = cv2.imdecode(np.frombuffer((rec.root / e["color"]).read_bytes(), np.uint8), cv2.IMREAD_UNCHANGED)
    raw = cv2.imdecode(np.frombuffer((rec.root / e["depth"]).read_bytes(), np.uint8), cv2.IMREAD_UNCHANGED)
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), depth_units_to_metres(raw, rec.depth_scale)


def run_session(session: int, seed: int, frames: int, pair: dict | None = None, odometry: str | None = None) -> dict:
    """Render, record, read back and track one session of the held-out design; its per-stage CPU times. ``pair``:
    TrackerConfig overrides of a second tracker run on the same frames in the same process (the two trackers take
    turns first on each frame), whose tracker CPU time is reported beside the default's (``tracker_pair``) with the
    per-frame difference (``pair_diff``: default minus paired, mean and its standard error). ``odometry``: the
    camera odometry mode of both (None: ``track``'s default)."""
    import cv2

    from app.commands.track import TrackSession
    from benchmarks.icp_baseline import ICPTracker
    from tracker.filter.tracker_config import TrackerConfig
    from tracker.odometry.ego_motion import DEFAULT_MODE
    from tracker.sources.recording import RecordingSource, RecordingWriter
    from tracker.sources.simulator import SimOptions, SimulatedTable

    cv2.setNumThreads(1)  # one core: OpenCV's own worker threads would escape the thread CPU time
    scenario, motion, occlusion, speed = DESIGN[session]
    opts = SimOptions(speed=speed, occlusion=occlusion, camera_motion=motion)
    src = SimulatedTable(scenario, seed=seed, options=opts, realtime=False, n_frames=frames)
    cfg = TrackerConfig.preset("default")
    odometry = odometry or DEFAULT_MODE
    cpu: dict[str, list[float]] = {k: [] for k in STAGES}
    with tempfile.TemporaryDirectory() as tmp:
        rec_dir = Path(tmp) / "rec"
        with RecordingWriter(rec_dir, src.intrinsics, parts=src.parts, initial_poses=src.initial_poses) as writer:
            for i in range(src.n_frames):
                frame = src.render(i)
                writer.write(frame, frame.meta.get("groundtruth"))
        # decoded on demand in this thread (no prefetch thread): one core does the decoding, as the target counts
        rec = RecordingSource(rec_dir, prefetch=0)
        ours = TrackSession(rec.parts, rec.intrinsics, rec.initial_poses, cfg, seed=0, odometry=odometry)
        other = None
        if pair:
            other = TrackSession(rec.parts, rec.intrinsics, rec.initial_poses, cfg.with_overrides(**pair), seed=0,
                                 odometry=odometry)
            cpu["tracker_pair"] = []
        icp = ICPTracker(rec.parts, rec.intrinsics)
        icp.initialize(rec.initial_poses)
        for i in range(len(rec)):
            c0 = time.thread_time()
            frame = rec.read(i)
            c1 = time.thread_time()
            if other is not None and i % 2:
                other.step(frame)
            c1b = time.thread_time()
            ours.step(frame)
            c2 = time.thread_time()
            if other is not None:
                if i % 2 == 0:
                    other.step(frame)
                cpu["tracker_pair"].append(1e3 * other.last_cpu)
            c2b = time.thread_time()
            plane = (ours.table.normal, ours.table.offset) if ours.table is not None else None
            icp.step(frame.depth, plane)
            c3 = time.thread_time()
            colour_cv, depth_cv = _decode_opencv(rec, i)
            c4 = time.thread_time()
            if i < 3 and not (np.array_equal(colour_cv, frame.color)
                              and np.array_equal(depth_cv, frame.depth, equal_nan=True)):
                raise AssertionError(f"frame {i}: the decoders' pixels differ")
            cpu["decode_opencv"].append(1e3 * (c4 - c3))
            cpu["decode"].append(1e3 * (c1 - c0))
            cpu["tracker"].append(1e3 * ours.last_cpu)
            cpu["perception"].append(1e3 * (c2 - c1b - ours.last_cpu))
            cpu["odometry"].append(1e3 * ours.last_ego_cpu)
            cpu["pipeline"].append(1e3 * (c1 - c0 + c2 - c1b))
            cpu["icp"].append(1e3 * (c3 - c2b))
    res = {"session": session, "scenario": scenario, "motion": motion, "occlusion": occlusion, "speed": speed,
           "seed": seed, "frames": len(cpu["tracker"]), "parts": len(rec.parts), "n_particles": cfg.n_particles,
           "icp_backend": icp.backend, "odometry_mode": odometry}
    for k, v in cpu.items():
        res[k] = _stats(v)
    if other is not None:
        d = (np.asarray(cpu["tracker"][3:]) - np.asarray(cpu["tracker_pair"][3:]))
        res["pair"] = pair
        res["pair_diff"] = {"mean": round(float(d.mean()), 2),
                            "stderr": round(float(d.std(ddof=1) / np.sqrt(max(d.size, 1))), 2)}
    res["fps_pipeline"] = round(1000.0 / res["pipeline"]["median"], 1)
    res["ratio_tracker_icp"] = round(res["tracker"]["median"] / res["icp"]["median"], 2)
    return res


def markdown(res: dict) -> str:
    m = res["machine"]
    odo = (res["sessions"][0].get("odometry_mode") if res["sessions"] else None) or "off"
    backend = res["sessions"][0]["icp_backend"] if res["sessions"] else "?"
    icp_name = "Open3D point-to-plane ICP" if backend == "open3d" else "point-to-plane ICP (numpy/scipy fallback)"
    lines = [
        "## Tracker speed on one core (issue 11)",
        "",
        f"Machine: {m['nproc']} cores, {m['cpu']}, Python {m['python']}; NUMBA_NUM_THREADS=1, OMP_NUM_THREADS=1, "
        f"OpenCV 1 thread. 1-minute load {m['load_avg_1min']} at the start and {res['load_1min_at_end']} at the "
        "end (other jobs shared the 2 cores: thread CPU time, shown here, is less affected than wall time, but "
        f"caches and memory bandwidth are shared). Commit {res['commit']}."
        + (f" {res['note']}" if res["note"] else ""),
        "",
        (f"Development run (`--dev`, tuning seeds, not for reporting) of `bench_heldout.py`'s design, {res['frames']} "
         "frames each, " if res.get("dev") else
         f"Held-out sessions of `bench_heldout.py`'s design (seeds >= 100, never tuned on), {res['frames']} frames "
         "each, ")
        +
        "written as a recording (PNG colour, 16-bit PNG depth) and read back as `assembly-agent track` reads it. "
        "Median thread CPU ms per frame (mean in brackets) of: **decode** (reading the colour and depth images), "
        "**perception** (table plane, colour detection and the camera odometry; **odometry** is the odometry's "
        f"share of it, mode `{odo}`), **tracker** (the tracker step, default preset, "
        "N = 225), **pipeline** (decode, perception and tracker; fps = 1000 / pipeline ms on one core). "
        f"**ICP** = {icp_name} per part, frame to frame, on the same frames in the same run "
        "(`benchmarks/icp_baseline.py`). **decode (OpenCV)**: the same two files decoded as the reader did before "
        "its own PNG decoder (`cv2.imdecode`; the pixels checked equal), the decode column's baseline.",
        "",
        "| # | scenario | camera | seed | parts | decode | perception | odometry | tracker | pipeline "
        "| fps (pipeline) | ICP | tracker / ICP | decode (OpenCV) | decode / OpenCV's |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in res["sessions"]:
        cells = " | ".join(f"{s[k]['median']:.1f} ({s[k]['mean']:.1f})" if k in s else "—"
                           for k in ("decode", "perception", "odometry", "tracker", "pipeline"))
        dec_cv = (f"{s['decode_opencv']['median']:.1f} ({s['decode_opencv']['mean']:.1f}) | "
                  f"{s['decode']['median'] / s['decode_opencv']['median']:.2f}") if "decode_opencv" in s else "— | —"
        lines.append(f"| {s['session']} | {s['scenario']} | {s['motion']} | {s['seed']} | {s['parts']} | {cells} | "
                     f"{s['fps_pipeline']:.1f} | {s['icp']['median']:.1f} | {s['ratio_tracker_icp']:.2f} | {dec_cv} |")
    paired = [s for s in res["sessions"] if "pair" in s]
    if paired:
        lines += ["", "Paired in the same run (a second tracker on the same frames, the two taking turns first): "
                  "tracker CPU ms, median (mean), and the mean per-frame difference default − paired ± its standard "
                  "error.", ""]
        names = ", ".join(f"`{k}={v}`" for k, v in paired[0]["pair"].items())
        lines += [f"| # | default | paired ({names}) | difference |", "|---|---|---|---|"]
        for s in paired:
            lines.append(f"| {s['session']} | {s['tracker']['median']:.1f} ({s['tracker']['mean']:.1f}) | "
                         f"{s['tracker_pair']['median']:.1f} ({s['tracker_pair']['mean']:.1f}) | "
                         f"{s['pair_diff']['mean']:+.1f} ± {s['pair_diff']['stderr']:.1f} |")
    lines += ["", "Targets (issue 11): 5 cubes >= 30 fps including decoding and perception; 7 cubes <= 15 ms tracker "
              "time per frame."]
    for s in res["sessions"]:
        if s["parts"] == 5:
            ok = s["fps_pipeline"] >= TARGET_FPS_5
            lines.append(f"- {s['scenario']} (5 cubes): {s['fps_pipeline']:.1f} fps on one core — "
                         + ("met." if ok else "not met."))
        elif s["parts"] == 7:
            ok = s["tracker"]["median"] <= TARGET_TRACKER_MS_7
            lines.append(f"- {s['scenario']} (7 cubes): {s['tracker']['median']:.1f} ms tracker time — "
                         + ("met." if ok else "not met."))
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sessions", default="0,1,15", help="sessions of the held-out design (default 0,1,15: static "
                    "with a fixed and with a hand-held camera, learning-5 with a swaying one)")
    ap.add_argument("--frames", type=int, default=150, help="frames per session (default 150)")
    ap.add_argument("--seed-base", type=int, default=100, help="session k gets seed base + k (default 100)")
    ap.add_argument("--note", default="", help="a sentence added to the report")
    ap.add_argument("--dev", action="store_true", help="development run on the tuning seeds (--seeds; session k gets "
                    "seeds[k mod count]); prints only, writes nothing")
    ap.add_argument("--seeds", default="0,1,2,3,4", help="with --dev only: the tuning seeds (default 0,1,2,3,4)")
    ap.add_argument("--pair", default="", help="KEY=VALUE[,KEY=VALUE] TrackerConfig overrides of a second tracker "
                    "run on the same frames in the same process (paired comparison, e.g. quiet_skip=true)")
    ap.add_argument("--odometry", default=None, choices=("off", "default", "fused"),
                    help="camera odometry of the tracked sessions (default: track's default, fused)")
    ap.add_argument("--no-write", action="store_true", help="print only; do not write benchmarks/results")
    ap.add_argument("--rewrite", action="store_true", help="rebuild the .md from the .json and exit")
    args = ap.parse_args(argv)
    if args.rewrite:
        print(rewrite_markdown("tracker_speed", markdown))
        return 0
    sessions = [int(s) for s in args.sessions.split(",") if s.strip()]
    if args.dev:
        pool = check_seeds([int(s) for s in args.seeds.split(",") if s.strip()], dev=True)
        seeds = [pool[k % len(pool)] for k in sessions]
    else:
        seeds = [args.seed_base + k for k in sessions]
        check_seeds(seeds, dev=False)
    res = {"machine": machine_info(), "commit": git_commit(), "frames": args.frames, "note": args.note,
           "sessions": [], "dev": bool(args.dev)}
    for k, seed in zip(sessions, seeds, strict=True):
        s = run_session(k, seed, args.frames, parse_overrides(args.pair) if args.pair else None, args.odometry)
        res["sessions"].append(s)
        print(f"session {k} ({s['scenario']}, {s['parts']} parts, seed {seed}): "
              + ", ".join(f"{st} {s[st]['median']:.1f} ms" for st in STAGES)
              + f"; {s['fps_pipeline']:.1f} fps pipeline", flush=True)
    res["load_1min_at_end"] = round(os.getloadavg()[0], 2)
    md = markdown(res)
    print(md)
    if not (args.no_write or args.dev):
        write_results("tracker_speed", res, md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
