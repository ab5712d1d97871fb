"""Assembly benchmark: per-frame cost of the modes, and the evaluation figures next to the thesis's numbers.

Usage::

    .venv/bin/python benchmarks/bench_assembly.py [--tracked DIR ...] [--groundtruth DIR ...] [--merge LABEL]

``DIR`` holds one sub-directory per experiment written by ``assembly-agent evaluate EXPERIMENT --out DIR/EXPERIMENT``
(guidance, guess, learning, sweep-*; a suffix such as ``guess-final`` is allowed). Writes
benchmarks/results/assembly.json and assembly.md. ``--merge LABEL`` keeps the rows already in assembly.json
(tracked ones renamed ``<name> LABEL``, e.g. ``[before]``) and adds the new ones.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import time
from pathlib import Path

import numpy as np

from tracker.assembly import build_mode, load_preset
from tracker.assembly.connection_monitor import specs_from_structure
from tracker.assembly.part_graph import PartGraph
from tracker.assembly.synthetic import build_up_session, default_table_to_camera
from tracker.evaluation.experiments import machine

RESULTS = Path(__file__).resolve().parent / "results"

THESIS = {
    "guidance": "28/30 connections recognised (93.3 %, rods, 2 per recording); mean deviation −1.49 s; "
                "within ±1 s unknown (Figs 6.7–6.8)",
    "guess": "15/16 correct (93.75 %, m_p = 1 cm, K = 3); 12/16 K = 2, 10/16 K = 5, 9/16 K = 7",
    "learning": "40/42 connections recognised (95.2 %); mean deviation −0.41 s; single correct order",
}


NOTES = [
    "- Sessions: the simulator's guidance-demo / guess-1..3 / learning-4,5 scenarios with six simulated users "
    "(speed 1.5/2/2.5, occlusion 0.5/1/1.6, out-of-view excursions for users 5 and 6), 15 / 16 / 12 sessions "
    "as in the thesis; 4 connections per guidance/guess session (the thesis's rods had 2).",
    "- Tracked runs process every 2nd frame (15 fps, `--frame-step 2`), tracker preset `default`, "
    "initialised with the first frame's true poses, hints from the mode every frame; parameters m_p = 1 cm, "
    "K = 3, N_max = 9, N_checks = 2, m_q = 45°, heading tolerance 40° (task presets).",
    "- `guess-rerun` / `learning-rerun` are the same experiments run again on the revision of that time "
    "(far-apart shortcut), a measure of the run-to-run spread of the tracked figures.",
    "- `guess-noyaw` is the ablation without the orientation-robust comparison (yaw_tolerance_deg = 0, "
    "m_q = 30°, priors re-anchored on the tracker's orientation).",
    "- The tracker's output varies from run to run (the same session re-run gave different connection "
    "results), so the tracked figures have a spread of several connections; the sweep used 4 sessions per "
    "setting only.",
    "- Ground-truth sweeps: K and N_max only change the tracker's connection particles, so they have no "
    "effect without the tracker; the ground-truth sweeps ran on a revision before the structural-prior "
    "change (irrelevant without orientation noise beyond 0.05 rad).",
    "- Rows marked `[before]` ran on the revisions before the final fix; the `-final` rows on the final "
    "revision. Cause of the tracked misses found then (per-frame traces of the missed sessions): (1) late or "
    "never: the positions were right (< 5 mm) but a released cube's tracked heading was often 30–48° off "
    "(between two faces), so with the 40° heading tolerance the connection failed for seconds, and a "
    "component whose first connection was vertical kept that wrong heading for good; (2) early (5–13 s): a "
    "cube covered by the hand got an unlocked Algorithm 6 hint and jumped onto its neighbour (the depth "
    "cannot refute a hidden cube's forced particles).",
    "- Fixes: cubes without a stored prior take their heading from the observed offset (assembly "
    "`free_yaw_tolerance_deg` = 180; the `-interim` rows used 45; a second cube's levelled heading residual "
    "is taken modulo 90°); a cube "
    "joining a component re-anchors the component's heading on its observed offset; the tracker forces a part "
    "with an unlocked hint only when it is visible (tracker `hint_min_visibility` = 0.5 and a reliable colour "
    "blob in the current frame; locked connections always apply).",
    "- Before the fixes on the same code path (16 guess sessions, one run each): 57/64 within ±1 s with "
    "hints; with the first two heading fixes 59/64 (0 never); + the visibility gate 59/64 (all misses late, "
    "none early); guidance with those three 57/60, learning 35/42 (sentences 10/12).",
    "- Revisions: `-interim` rows = commit 2b5dd59 (all fixes, free heading bound 45°), `-final` rows = "
    "c40571b (bound 180°). `guess-final-rerun` repeated `guess-final` and gave identical figures (the "
    "seeded pipeline is now reproducible on this machine).",
    "- Still missing (guidance, 3/60 never): all three are the last step, yellow on top of the centre cube "
    "green; the tracker's estimate of green (covered by yellow and the hand) stays ~1.5 cm off (too high), so "
    "the measured vertical offset is 2.4–2.9 cm instead of 3.6 cm and the m_p = 1 cm test fails: a tracker "
    "accuracy issue that the assembly side cannot fix without loosening the margins.",
    "- On ground truth + noise every connection is detected within ±1 s (typically 0.07 s early: the cube is "
    "within the margins while it is lowered).",
]


def time_modes(frames_per_step: int = 10) -> dict:
    """Mean wall time of ``mode.update`` per frame on a scripted session (no tracker), milliseconds."""
    T = default_table_to_camera()
    out = {}
    for task_id in ("guidance-5-cubes", "guess-structures", "learning-5-words"):
        task = load_preset(task_id)
        mode = build_mode(task, seed=0)
        if task.mode == "learning":
            cubes = ["red", "green", "blue", "yellow", "orange"]
            from tracker.assembly.connection_monitor import ConnectionSpec

            specs = [ConnectionSpec(a, b, np.array([task.edge, 0, 0]), np.eye(3))
                     for a, b in zip(cubes[:-1], cubes[1:], strict=True)]
            graph, order, extra = PartGraph.from_connections(specs), cubes, ["purple", "cyan"]
        else:
            s = task.structures[0]
            graph = PartGraph.from_connections(specs_from_structure(task, s))
            order, extra = s.plan or list(graph.parts), None
        frames = build_up_session(graph, order, T, np.random.default_rng(0), extra_parts=extra,
                                  frames_per_step=frames_per_step)
        t0 = time.perf_counter()
        for t, poses, _ in frames:
            mode.update(t, poses, T)
            mode.connection_hints()
        out[task.mode] = round(1000 * (time.perf_counter() - t0) / len(frames), 3)
    return out


def load_summaries(root: Path | None) -> dict:
    if root is None or not root.is_dir():
        return {}
    out = {}
    for d in sorted(root.iterdir()):
        f = d / "summary.json"
        if f.is_file():
            out[d.name] = json.loads(f.read_text())
    return out


def _row(name: str, s: dict) -> str:
    tot = s.get("connections_total", 0)
    w1 = s.get("connections_within_1s", 0)
    rate = f"{100 * w1 / tot:.1f} %" if tot else "–"
    extra = ""
    if "guess_correct" in s:
        extra = f"guess {s['guess_correct']}/{s['sessions']}"
    if "sentences_correct" in s:
        extra = f"sentences {s['sentences_correct']}/{s['sessions']}"
    within = s.get("within_rate", {})
    wr = " / ".join(f"{100 * within[k]:.0f}" for k in ("1", "2", "3", "4") if k in within)
    return (f"| {name} | {s.get('sessions')} | {w1}/{tot} ({rate}) | {wr} | {s.get('connections_never')} | "
            f"{s.get('mean_deviation_s')} | {s.get('false_completions')} | {extra} | {s.get('wall_seconds')} |")


def render_md(timing: dict, tracked: dict, gt: dict) -> str:
    m = machine()
    lines = [
        "## Assembly engine and modes (engineer 5)",
        "",
        f"Machine: {m['nproc']} cores, {m['cpu']}; shared with five other engineers while measured, so wall "
        "times are pessimistic.",
        "",
        "Per-frame cost of `mode.update` + `connection_hints()` (no tracker; ms; scripted session): "
        + ", ".join(f"{k} {v}" for k, v in timing.items()) + ".",
        "",
        "Columns: within ±1 s (count and share), share within ±T for T = 1/2/3/4 s (%), never detected, mean "
        "deviation (detected − true, s; negative = early), false \"complete\" reports, verdicts, wall time (s).",
        "",
    ]
    header = ("| experiment | sessions | within ±1 s | within ±T=1/2/3/4 s (%) | never | mean dev. (s) |"
              " false complete | verdicts | wall (s) |\n|---|---|---|---|---|---|---|---|---|")
    for title, data in (("Tracked poses (simulated frames → colour → table → particle filter, hints on)", tracked),
                        ("Ground truth + noise (σ 3 mm, 0.05 rad; no tracker)", gt)):
        if not data:
            continue
        lines += [f"### {title}", "", header]
        for name, s in data.items():
            if "settings" in s:
                for label, sub in s["settings"].items():
                    lines.append(_row(f"{name}: {label}", sub))
            else:
                lines.append(_row(name, s))
        lines.append("")
    lines += ["### Notes", "", *NOTES, ""]
    lines += ["### The thesis's numbers (spec section 18)", ""]
    lines += [f"- {k}: {v}" for k, v in THESIS.items()]
    lines.append("")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--tracked", type=Path, nargs="*", default=[])
    ap.add_argument("--groundtruth", type=Path, nargs="*", default=[])
    ap.add_argument("--merge", default=None, help="keep the rows of the existing assembly.json; label its tracked rows")
    args = ap.parse_args()
    timing = time_modes()
    tracked, gt = {}, {}
    if args.merge is not None and (RESULTS / "assembly.json").is_file():
        old = json.loads((RESULTS / "assembly.json").read_text())
        for name, s in old.get("tracked", {}).items():
            key = name if name.endswith("]") or "final" in name else f"{name} {args.merge}"
            tracked[key] = s
        gt.update(old.get("groundtruth", {}))
    for d in args.tracked:
        tracked.update(load_summaries(d))
    for d in args.groundtruth:
        gt.update(load_summaries(d))
    RESULTS.mkdir(parents=True, exist_ok=True)
    for d in args.tracked:  # plots of the tracked main experiments, as assembly.<experiment>_<plot>.png
        for sub in sorted(d.iterdir()) if d.is_dir() else []:
            name = sub.name.split("-")[0]
            if name not in ("guidance", "guess", "learning"):
                continue
            for kind in ("timing", "confusion"):
                src = sub / f"{name}_{kind}.png"
                if src.is_file():
                    shutil.copyfile(src, RESULTS / f"assembly.{name}_{kind}.png")
    RESULTS.mkdir(parents=True, exist_ok=True)
    data = {"machine": machine(), "mode_update_ms": timing, "tracked": tracked, "groundtruth": gt,
            "load": os.getloadavg()}
    (RESULTS / "assembly.json").write_text(json.dumps(data, indent=1, default=str))
    md = render_md(timing, tracked, gt)
    (RESULTS / "assembly.md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()
