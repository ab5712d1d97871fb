"""Batch evaluation speed: ``evaluate EXPERIMENT --ray`` (a local Ray runtime) against the serial run (baseline).

Runs the same experiment on the same held-out seeds once per runner (:mod:`tracker.evaluation.batch`: ``serial``
first, the baseline, then ``ray``, optionally ``processes``), each into its own output folder, and reports per
runner the wall time of the whole batch (Ray's start-up included), the sum of the sessions' own wall times, the
speed-up serial / runner, and whether its summary and per-session results equal the serial run's (timings left
out). A short warm-up session first fills numba's on-disk cache, so no runner pays the kernels' first compilation.
Writes ``benchmarks/results/batch.json`` and ``batch.md`` (a section of BENCHMARKS.md).

Usage::

    .venv/bin/python benchmarks/bench_batch.py [--experiment guess] [--seeds 100-115] [--poses tracked]
        [--frame-step 2] [--runners serial,ray] [--sessions N] [--max-time S]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.result_files import git_commit, rewrite_markdown, write_results  # noqa: E402
from tracker.evaluation import run_experiment  # noqa: E402
from tracker.evaluation.batch import ProcessPoolRunner, RayRunner, SerialRunner, usable_cores  # noqa: E402
from tracker.evaluation.machine_info import machine_info  # noqa: E402
from tracker.evaluation.seeds import check_seeds, parse_seeds  # noqa: E402

TIMING = ("wall_seconds", "elapsed_seconds", "runner", "machine")


def _load() -> float | None:
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return None


def _results(out: Path, name: str) -> tuple[dict, list[dict]]:
    """The run's summary and per-session results without their timings (what must equal the serial run's)."""
    summary = json.loads((out / "summary.json").read_text())
    sessions = []
    for f in sorted(out.glob(f"{name}*_sessions.json")):
        for s in json.loads(f.read_text()):
            s.pop("seconds", None)
            sessions.append(s)
    return {k: v for k, v in summary.items() if k not in TIMING}, sessions


def markdown(res: dict) -> str:
    m = res["machine"]
    loads = [r["load_1min_start"] for r in res["runs"]] + [r["load_1min_end"] for r in res["runs"]]
    loaded = max((x or 0) for x in loads) > 1.5
    lines = [
        "## Batch evaluation: Ray against serial (issue 16)",
        "",
        f"Machine: {m['nproc']} cores, {m['cpu']}, Python {m['python']}. Commit {res['commit']}. "
        f"`evaluate {res['experiment']}` on {res['sessions']} sessions, seeds {res['seeds_text']} (held out), "
        f"{res['poses']} poses, frame step {res['frame_step']}"
        + (f", each session stopped at {res['max_time']:g} s" if res["max_time"] else "") + ". "
        "The runners run one after the other on the same sessions; **serial** (one process, the baseline) first. "
        "Wall time = the whole batch as the user waits for it (Ray's local runtime start-up and the workers' "
        "imports included); session time = the sum of the sessions' own wall times (what a session costs where it "
        "runs). Identical = the summary and every session's result (detections, guesses, final state) equal the "
        "serial run's, timings left out."
        + (" Taken under load (other agents' jobs shared the 2 cores; 1-minute load in the table), so the wall "
           "times are pessimistic and the speed-up is smaller than on an idle machine." if loaded else "")
        + (f" {res['note']}" if res.get("note") else ""),
        "",
        "| runner | wall s | session s (sum) | speed-up vs serial | identical to serial | load 1 min start / end |",
        "|---|---|---|---|---|---|",
    ]
    base = res["runs"][0]["wall_s"]
    for r in res["runs"]:
        lines.append(f"| {r['runner']} | {r['wall_s']:.1f} | {r['session_s']:.1f} | {base / r['wall_s']:.2f}× | "
                     f"{'yes' if r['identical'] else 'NO'} | {r['load_1min_start']} / {r['load_1min_end']} |")
    lines += ["", f"Reproduce: `.venv/bin/python benchmarks/bench_batch.py {res['args']}`".rstrip() + "", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--experiment", default="guess")
    ap.add_argument("--seeds", default="100-115", help="held-out simulator seeds (>= 100); session k takes the k-th")
    ap.add_argument("--poses", choices=["tracked", "groundtruth"], default="tracked")
    ap.add_argument("--frame-step", type=int, default=2)
    ap.add_argument("--sessions", type=int, default=None, help="only N sessions of the experiment")
    ap.add_argument("--max-time", type=float, default=None, help="stop each session after S seconds")
    ap.add_argument("--note", default="", help="a sentence for the report (e.g. what else ran meanwhile)")
    ap.add_argument("--rewrite", action="store_true", help="only rebuild batch.md from batch.json (with --note)")
    ap.add_argument("--runners", default="serial,ray", help="comma-separated: serial (always first), ray, processes")
    args = ap.parse_args(argv)
    if args.rewrite:
        def with_note(res: dict) -> str:
            res["note"] = args.note or res.get("note", "")
            return markdown(res)

        print(rewrite_markdown("batch", with_note))
        return 0
    seeds = check_seeds(parse_seeds(args.seeds))
    names = ["serial"] + [n for n in args.runners.split(",") if n and n != "serial"]
    cores = usable_cores()
    runners = {"serial": SerialRunner, "ray": RayRunner, "processes": lambda: ProcessPoolRunner(cores)}
    unknown = [n for n in names if n not in runners]
    if unknown:
        raise SystemExit(f"unknown runner(s) {unknown}; choose from {list(runners)}")
    # Warm-up: one short session compiles the numba kernels into their on-disk cache, so that no runner pays the
    # first compilation (the serial run keeps them in memory, the workers load them from the cache).
    print("warm-up: one short session ...", flush=True)
    with tempfile.TemporaryDirectory(prefix="bench_batch_warm_") as tmp:
        run_experiment(args.experiment, tmp, sessions=1, poses=args.poses, frame_step=args.frame_step, seeds=seeds,
                       max_time=1.0)
    runs, reference = [], None
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        for name in names:
            runner = runners[name]()
            out = Path(tmp) / name
            load0 = _load()
            print(f"{name}: running ({runner.describe()}) ...", flush=True)
            summary = run_experiment(args.experiment, out, sessions=args.sessions, poses=args.poses,
                                     frame_step=args.frame_step, seeds=seeds, runner=runner, max_time=args.max_time,
                                     progress=lambda line, n=name: print(f"  {n}: {line}", flush=True))
            got = _results(out, args.experiment)
            reference = reference or got
            runs.append({"runner": runner.describe(), "wall_s": summary["elapsed_seconds"],
                         "session_s": summary["wall_seconds"], "identical": got == reference,
                         "load_1min_start": load0, "load_1min_end": _load()})
            print(f"{name}: {runs[-1]}", flush=True)
            n_sessions = summary["sessions_run"]
    res = {"machine": machine_info(), "commit": git_commit(), "experiment": args.experiment, "seeds": seeds,
           "seeds_text": args.seeds, "poses": args.poses, "frame_step": args.frame_step, "max_time": args.max_time,
           "sessions": n_sessions, "runs": runs, "note": args.note,
           "args": " ".join(argv if argv is not None else sys.argv[1:])}
    md = markdown(res)
    print(md)
    write_results("batch", res, md)
    return 0 if all(r["identical"] for r in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
