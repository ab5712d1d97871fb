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
    p.add_argument("--hands", action="store_true", help="run the hand tracker on the rendered frames (tracked poses): "
                   "occluder prior and the connection gate (off with --set hand_gate=0)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override an assembly parameter for every session (m_p, m_q_deg, yaw_tolerance_deg, K, "
                   "N_max, N_checks, N_break, break_factor, hand_gate, n_release); repeatable")
    p.add_argument("--seeds", default=None, help="simulator seeds, e.g. 100-115 or 100,105. Hands experiments: the "
                   "seeds to run (default: the held-out 100,101,102 for 'hands', 100 for 'hands-particles'); the "
                   "others: they replace the sessions' own seeds (session k takes the k-th, cycling; default: each "
                   "session's built-in seed, >= 1011). Seeds 0-4 are for tuning only; report only seeds >= 100")
    p.add_argument("--seed", type=int, default=None, help="one simulator seed (= --seeds S)")
    p.add_argument("--runs", type=int, default=5, help="hands experiments: runs per particle-filter configuration (5)")
    p.add_argument("--frames", type=int, default=None, help="hands experiments: frames per sequence (default: all)")
    p.add_argument("--max-time", type=float, default=None, metavar="SECONDS",
                   help="stop each session after this many seconds of its recording (a short run)")
    p.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                   help="spread the sessions over Ray: a local Ray runtime on this machine's cores (no ADDRESS) or "
                   "the cluster at ADDRESS ('auto' = the one 'ray start' runs here, HOST:PORT, ray://HOST:PORT; "
                   "every node needs this package installed). Results equal the serial run's. Needs the 'ray' extra")
    p.add_argument("--jobs", type=int, default=1, metavar="N",
                   help="run N sessions at a time in local worker processes (default 1 = serial in this process)")
    p.add_argument("--list", action="store_true", help="list the experiments and exit")
    p.set_defaults(func=run)


HAND_EXPERIMENTS = {
    "hands": "hand tracking Experiment 1: particle filter (5 runs) vs Kalman reference vs CamShift on S1-S3, plus "
             "automatic track start (e_p, F_b, F_c, runtime, plots)",
    "hands-particles": "hand tracking Experiment 2: particle count N_s in 10..150, 5 runs each, metrics and runtime",
}


def _seeds(args: argparse.Namespace) -> list[int] | None:
    """The seeds of ``--seeds``/``--seed`` (None when neither is given); a note on stdout for tuning seeds."""
    from tracker.evaluation.seeds import TUNING_SEEDS, parse_seeds

    if args.seed is not None and args.seeds is not None:
        raise ValueError("give --seed or --seeds, not both")
    if args.seeds is None and args.seed is None:
        return None
    seeds = parse_seeds(args.seeds if args.seeds is not None else str(args.seed))
    tuning = [s for s in seeds if s in TUNING_SEEDS]
    if tuning:
        print(f"note: seeds {tuning} are tuning seeds; do not report these figures (held-out seeds are >= 100)")
    return seeds


def run_hands(args: argparse.Namespace) -> int:
    import cv2

    from tracker.evaluation.hands import experiment_1, experiment_2

    # one core, as the server's hand process (tracker.hands.process) and bench_hands.py: the runtime table is
    # thread CPU time, which OpenCV's worker threads (the optical flow) would escape
    cv2.setNumThreads(1)
    default = "100,101,102" if args.experiment == "hands" else "100"
    seeds = tuple(_seeds(args) or [int(x) for x in default.split(",")])
    if not seeds or args.runs < 1:
        raise ValueError("give at least one seed and --runs >= 1")
    if args.experiment == "hands":
        summary = experiment_1(args.out, seeds=seeds, runs=args.runs, n_frames=args.frames)
    else:
        summary = experiment_2(args.out, seeds=seeds, runs=args.runs, n_frames=args.frames)
    print(f"wrote {args.out}: {', '.join(k for k in summary if not k.startswith('_'))}")
    return 0


def run(args: argparse.Namespace) -> int:
    from tracker.evaluation import EXPERIMENTS, run_experiment, tracked_available

    if args.list:
        for e in EXPERIMENTS.values():
            print(f"{e.name:16s} {e.description}")
        for name, desc in HAND_EXPERIMENTS.items():
            print(f"{name:16s} {desc}")
        return 0
    if not args.experiment:
        raise ValueError("name an experiment (see --list)")
    if not args.out:
        raise ValueError("--out DIR is required")
    if args.experiment in HAND_EXPERIMENTS:
        return run_hands(args)
    overrides = {}
    for item in args.set:
        key, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"--set expects KEY=VALUE, got {item!r}")
        try:
            overrides[key.strip()] = float(value)
        except ValueError:
            raise ValueError(f"--set {key}: value must be a number, got {value!r}") from None
    seeds = _seeds(args)
    poses = args.poses or ("tracked" if tracked_available() else "groundtruth")
    if args.max_time is not None and args.max_time <= 0:
        raise ValueError("--max-time must be positive")
    from tqdm import tqdm

    from tracker.evaluation.batch import make_runner
    from tracker.evaluation.sessions import sessions_for

    runner = make_runner(ray=args.ray, jobs=args.jobs)
    exp = EXPERIMENTS.get(args.experiment)
    n_specs = len(sessions_for(exp.base)) if exp is not None else 0
    total = min(args.sessions or n_specs, n_specs) * (len(exp.settings) if exp is not None else 0)
    if not runner.frame_progress:
        print(f"running {total} session{'s' if total != 1 else ''} on {runner.describe()}")
    with tqdm(total=total, unit="session", desc=args.experiment, disable=None, dynamic_ncols=True,
              bar_format="{l_bar}{bar}| {n:.1f}/{total} sessions [{elapsed}<{remaining}]") as bar:

        def on_frame(i: int, n: int) -> None:  # fractions of a session: the ETA moves during a session
            bar.update(min(args.frame_step, n - i) / max(1, n))

        def on_session(n_done: int, n_total: int) -> None:  # parallel runners: whole sessions as they finish
            if not runner.frame_progress:
                bar.update(1)

        summary = run_experiment(args.experiment, args.out, sessions=args.sessions, poses=poses,
                                 frame_step=args.frame_step, n_particles=args.particles, progress=bar.write,
                                 tracker_preset=args.tracker_preset, hints=not args.no_hints, overrides=overrides,
                                 on_frame=on_frame, seeds=seeds, runner=runner, on_session=on_session,
                                 max_time=args.max_time, hands=args.hands)
    keys = ("sessions", "sessions_in_experiment",
            "connections_total", "connections_within_1s", "connections_never", "false_completions",
            "guess_correct", "sentences_correct", "mean_deviation_s", "runner", "elapsed_seconds")
    print(json.dumps({k: summary[k] for k in keys if k in summary}))
    return 0
