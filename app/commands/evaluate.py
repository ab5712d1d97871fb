"""``assembly-agent evaluate``: the thesis's experiments on simulated sessions (guidance, guess, learning)."""

from __future__ import annotations

import argparse
import json


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "evaluate",
        help="run an evaluation experiment on simulated sessions",
        description="Run the seed's experiments (guidance, guess, learning) or a parameter sweep on simulated "
        "users; writes <experiment>.md tables, PNG plots and summary.json into --out.",
    )
    p.add_argument("experiment", nargs="?", help="experiment name (see --list)")
    p.add_argument("--out", default=None, help="output directory (required unless --list)")
    p.add_argument("--sessions", type=int, default=None, help="run only N sessions, spread over the full set")
    p.add_argument("--poses", choices=["tracked", "groundtruth"], default=None,
                   help="pose source: the depth tracker on rendered frames (default when available) or the "
                   "simulator's ground truth plus noise")
    p.add_argument("--frame-step", type=int, default=1, help="process every N-th frame (default 1 = 30 fps)")
    p.add_argument("--particles", type=int, default=None, help="tracker particle count (default: the preset's)")
    p.add_argument("--tracker-preset", default="default", help="tracker preset for --poses tracked (default|seed-exp1|"
                   "seed-exp23)")
    p.add_argument("--no-hints", action="store_true", help="do not feed connection hints to the tracker (ablation)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override an assembly parameter for every session (m_p, m_q_deg, yaw_tolerance_deg, K, "
                   "N_max, N_checks, N_break, break_factor); repeatable")
    p.add_argument("--list", action="store_true", help="list the experiments and exit")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from tracker.evaluation import EXPERIMENTS, run_experiment, tracked_available

    if args.list:
        for e in EXPERIMENTS.values():
            print(f"{e.name:16s} {e.description}")
        return 0
    if not args.experiment:
        raise ValueError("name an experiment (see --list)")
    if not args.out:
        raise ValueError("--out DIR is required")
    overrides = {}
    for item in args.set:
        key, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"--set expects KEY=VALUE, got {item!r}")
        try:
            overrides[key.strip()] = float(value)
        except ValueError:
            raise ValueError(f"--set {key}: value must be a number, got {value!r}") from None
    poses = args.poses or ("tracked" if tracked_available() else "groundtruth")
    from tqdm import tqdm

    from tracker.evaluation.sessions import sessions_for

    exp = EXPERIMENTS.get(args.experiment)
    n_specs = len(sessions_for(exp.base)) if exp is not None else 0
    total = min(args.sessions or n_specs, n_specs) * (len(exp.settings) if exp is not None else 0)
    with tqdm(total=total, unit="session", desc=args.experiment, disable=None, dynamic_ncols=True,
              bar_format="{l_bar}{bar}| {n:.1f}/{total} sessions [{elapsed}<{remaining}]") as bar:

        def on_frame(i: int, n: int) -> None:  # fractions of a session: the ETA moves during a session
            bar.update(min(args.frame_step, n - i) / max(1, n))

        summary = run_experiment(args.experiment, args.out, sessions=args.sessions, poses=poses,
                                 frame_step=args.frame_step, n_particles=args.particles, progress=bar.write,
                                 tracker_preset=args.tracker_preset, hints=not args.no_hints, overrides=overrides,
                                 on_frame=on_frame)
    keys = ("sessions", "sessions_in_experiment",
            "connections_total", "connections_within_1s", "connections_never", "false_completions",
            "guess_correct", "sentences_correct", "mean_deviation_s")
    print(json.dumps({k: summary[k] for k in keys if k in summary}))
    return 0
