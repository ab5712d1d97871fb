"""The evaluation experiments (``assembly-agent evaluate --list``) and their runner.

Main experiments (the thesis's, spec section 12): ``guidance`` (15 sessions), ``guess`` (16 sessions over
3 structures), ``learning`` (12 sessions, 4 and 5 words), each with the task preset's parameters.
Sweeps repeat an experiment over parameter settings: ``sweep-guidance`` (Fig. 6.8's four curves: K, N_max,
N_checks), ``sweep-guess`` (m_p ∈ {1, 1.8} cm × K ∈ {2, 3, 5, 7}, Fig. 6.9/6.10), ``sweep-learning``
(m_p 1.8 cm / K 5 against m_p 1 cm / K 3, Figs 6.11–6.14, and N_checks), ``sweep-mp`` (m_p on guess).
Note: K and N_max only change the tracker's connection particles, so on ground-truth poses they have no
effect; m_p and N_checks do.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field, replace
from pathlib import Path

from tracker.evaluation.batch import BatchRunner, SerialRunner, SessionJob, timed
from tracker.evaluation.machine_info import machine_info
from tracker.evaluation.metrics import summarize, timing_distribution
from tracker.evaluation.report import markdown_table, plot_sweep, write_experiment
from tracker.evaluation.sessions import GUESS_STRUCTURES, sessions_for

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Experiment:
    name: str
    base: str
    description: str
    settings: list[dict] = field(default_factory=lambda: [{}])


EXPERIMENTS: dict[str, Experiment] = {
    e.name: e
    for e in (
        Experiment("guidance", "guidance", "Exp. 1: 15 guided builds of the five-cube target (4 connections each)"),
        Experiment("guess", "guess", "Exp. 2: 16 builds of one of 3 structures; intention recognition"),
        Experiment("learning", "learning", "Exp. 3: 12 Spanish sentences (six of 4, six of 5 words)"),
        Experiment("sweep-guidance", "guidance", "guidance with Fig. 6.8's settings (K, N_max, N_checks)",
                   [{"K": 7, "N_max": 12, "N_checks": 4}, {"K": 9, "N_max": 12, "N_checks": 4},
                    {"K": 7, "N_max": 8, "N_checks": 4}, {"K": 7, "N_max": 12, "N_checks": 6}]),
        Experiment("sweep-guess", "guess", "guess over m_p ∈ {1, 1.8} cm × K ∈ {2, 3, 5, 7}",
                   [{"m_p": m, "K": k} for m in (0.01, 0.018) for k in (2, 3, 5, 7)]),
        Experiment("sweep-learning", "learning", "learning: m_p 1.8 cm K 5 vs m_p 1 cm K 3, N_checks 2 / 4",
                   [{"m_p": 0.018, "K": 5}, {"m_p": 0.01, "K": 3}, {"m_p": 0.01, "K": 3, "N_checks": 4}]),
        Experiment("sweep-mp", "guess", "guess over m_p ∈ {0.5, 1, 1.5, 2} cm and N_checks ∈ {1, 2, 4}",
                   [{"m_p": m} for m in (0.005, 0.01, 0.015, 0.02)] + [{"N_checks": n} for n in (1, 4)]),
    )
}


def tracked_available() -> bool:
    try:
        import tracker.filter.particle_filter  # noqa: F401
        import tracker.perception.color_detection  # noqa: F401
        import tracker.perception.table_plane  # noqa: F401
    except ImportError:
        return False
    return True


def machine() -> dict:
    return machine_info()


def _label(setting: dict) -> str:
    return ", ".join(f"{k}={v}" for k, v in setting.items()) or "preset"


def _ran(n: int, n_all: int) -> str:
    """What was run, for the report's first line (a partial run says so)."""
    if n == n_all:
        return f"Ran all {n} sessions."
    return f"Ran {n} of its {n_all} sessions (--sessions {n}): figures are for those only."


def run_experiment(name: str, out: str | Path, sessions: int | None = None, poses: str = "groundtruth",
                   frame_step: int = 1, n_particles: int | None = None, progress=None,
                   tracker_preset: str = "default", hints: bool = True, overrides: dict | None = None,
                   on_frame=None, seeds: list[int] | None = None, runner: BatchRunner | None = None,
                   on_session=None, max_time: float | None = None, hands: bool = False) -> dict:
    """Run experiment ``name``, write its report into ``out`` and return the summary (also summary.json).

    ``progress(text)``: one line per finished session; ``on_frame(i, n)``: after each frame ``i`` of a session's
    ``n`` (a progress bar). The report says how many of the experiment's sessions were run. ``seeds``: simulator
    seeds replacing the sessions' own (session k of the run gets ``seeds[k mod len]``; user profile, scenario and
    task are kept); default: each session's built-in seed (≥ 1011, see :mod:`tracker.evaluation.sessions`). Seeds
    0–4 are tuning seeds (:mod:`tracker.evaluation.seeds`).

    ``runner``: how the sessions run (:mod:`tracker.evaluation.batch`: serial by default, a process pool or Ray);
    the results are merged in the sessions' order, so the figures equal the serial run's. ``on_session(n_done,
    n_total)``: after each finished session (all settings of a sweep together). ``max_time``: stop each session
    after this many seconds of its recording (a short run; connections after it count as missed). ``hands``: run the
    hand tracker and its connection gate (tracked poses only; see :func:`~tracker.evaluation.runner.run_session`)."""
    if name not in EXPERIMENTS:
        raise ValueError(f"unknown experiment {name!r}; choose one of {list(EXPERIMENTS)}")
    exp = EXPERIMENTS[name]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    specs = sessions_for(exp.base)
    n_all = len(specs)
    if sessions is not None:
        if sessions < 1:
            raise ValueError("--sessions must be at least 1")
        specs = _spread(specs, sessions)
    if seeds is not None:
        if not seeds:
            raise ValueError("seeds: give at least one seed")
        specs = [replace(spec, seed=int(seeds[k % len(seeds)])) for k, spec in enumerate(specs)]
    structures = list(GUESS_STRUCTURES.values()) if exp.base == "guess" else None
    per_setting = {}
    curves = {}
    runner = runner or SerialRunner()
    common = {"poses": poses, "frame_step": frame_step, "n_particles": n_particles, "tracker_preset": tracker_preset,
              "hints": hints, "max_time": max_time, "hands": hands}
    jobs = [SessionJob(spec, {**common, "overrides": {**(overrides or {}), **setting}})
            for setting in exp.settings for spec in specs]

    def done(k: int, r, n_done: int) -> None:
        setting, spec = exp.settings[k // len(specs)], specs[k % len(specs)]
        if progress:
            progress(f"{name} [{_label(setting)}] session {spec.index + 1} ({spec.scenario}, user {spec.user}): "
                     f"{summarize([r])['connections_detected']}/{len(r.truth_events)} detected, "
                     f"{r.frames} frames in {r.seconds:.1f} s" + ("" if runner.frame_progress else
                                                                  f" [{n_done}/{len(jobs)} done]"))
        if on_session:
            on_session(n_done, len(jobs))

    all_results, elapsed = timed(runner, jobs, on_done=done, on_frame=on_frame)
    for i, setting in enumerate(exp.settings):
        results = all_results[i * len(specs):(i + 1) * len(specs)]
        summary = summarize(results)
        label = _label(setting)
        tag = name if len(exp.settings) == 1 else f"{name}_{len(per_setting) + 1}"
        write_experiment(out, tag, results, summary, structures,
                         header=f"{exp.description}. {_ran(len(results), n_all)} Poses: {poses}"
                                f"{' with hand tracking' if hands else ''}; setting: {label}; "
                                f"parameters: {results[0].params if results else {}}.\n")
        summary["setting"] = setting
        per_setting[label] = summary
        curves[label] = timing_distribution(results)
    if len(exp.settings) == 1:
        summary = dict(next(iter(per_setting.values())))
    else:
        plot_sweep(curves, out / f"{name}_sweep.png", f"{name} ({poses} poses)")
        rows = [{"setting": k, "within_1s": v["connections_within_1s"], "never": v["connections_never"],
                 "total": v["connections_total"], "mean_dev_s": v["mean_deviation_s"],
                 "false_completions": v["false_completions"], "guess_correct": v.get("guess_correct")}
                for k, v in per_setting.items()]
        (out / f"{name}.md").write_text(f"## {name}\n\n{exp.description}. {_ran(len(specs), n_all)} Poses: {poses}.\n\n"
                                        + markdown_table(rows))
        first = next(iter(per_setting.values()))
        summary = {k: sum(s[k] for s in per_setting.values()) for k in
                   ("sessions", "connections_total", "connections_within_1s", "connections_never", "false_completions")}
        if "guess_correct" in first:
            summary["guess_correct"] = sum(s["guess_correct"] for s in per_setting.values())
        summary["settings"] = per_setting
    summary.update({"sessions_run": len(specs), "sessions_in_experiment": n_all})
    summary.update({"experiment": name, "poses": poses, "frame_step": frame_step, "machine": machine(),
                    "tracker_preset": tracker_preset if poses == "tracked" else None, "hints": hints,
                    "overrides": overrides or {}, "max_time": max_time, "seeds": [spec.seed for spec in specs],
                    "runner": runner.describe(), "elapsed_seconds": round(elapsed, 2), "hands": hands})
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    return summary


def _spread(specs: list, n: int) -> list:
    """``n`` sessions spread over the list (so a small subset still covers several structures/users)."""
    if n >= len(specs):
        return specs
    step = len(specs) / n
    return [specs[int(i * step)] for i in range(n)]
