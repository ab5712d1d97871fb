"""Metrics of the thesis (spec section 12): connection timing within ±T, deviations, guess confusion."""

from __future__ import annotations

import numpy as np

from tracker.evaluation.runner import SessionResult

TOLERANCES = (1.0, 2.0, 3.0, 4.0)
"""T in seconds."""


def connection_matches(r: SessionResult) -> list[dict]:
    """Each true connection with the time of its first detection (``None`` = never detected)."""
    det = {frozenset((a, b)): t for t, a, b in r.detected_events}
    return [{"pair": [a, b], "t_true": t, "t_detected": det.get(frozenset((a, b)))} for t, a, b in r.truth_events]


def classify(t_true: float, t_det: float | None, T: float) -> str:
    """``early`` (more than T before), ``within`` (±T), ``late`` (more than T after) or ``never``."""
    if t_det is None:
        return "never"
    d = t_det - t_true
    return "early" if d < -T else "late" if d > T else "within"


def timing_distribution(results: list[SessionResult]) -> dict[str, dict[str, int]]:
    """``{T: {early, within, late, never}}`` over all true connections of ``results``."""
    out = {}
    for T in TOLERANCES:
        c = {"early": 0, "within": 0, "late": 0, "never": 0}
        for r in results:
            for m in connection_matches(r):
                c[classify(m["t_true"], m["t_detected"], T)] += 1
        out[f"{T:g}"] = c
    return out


def session_row(r: SessionResult) -> dict:
    """One row of a Table 6.1–6.3-like table."""
    ms = connection_matches(r)
    devs = [m["t_detected"] - m["t_true"] for m in ms if m["t_detected"] is not None]
    from tracker.evaluation.sessions import USERS

    u = USERS[r.spec.user]
    row = {
        "session": r.spec.index + 1,
        "user": r.spec.user,
        "rec": r.spec.recording,
        "scenario": r.spec.scenario,
        "completion_s": None if r.completion_true is None else round(r.completion_true, 2),
        "occlusions": u.occlusion_label,
        "out_of_view": "yes" if u.excursions else "no",
        "speed": u.speed_label,
        "recognised": sum(1 for m in ms if m["t_detected"] is not None),
        "connections": len(ms),
        "deviation_s": round(float(np.mean(devs)), 2) if devs else None,
        "false_completions": r.false_completions,
    }
    if r.spec.experiment == "guess":
        row["true"] = r.spec.truth
        row["guess"] = r.final_guess
    if r.spec.experiment == "learning":
        row["words"] = r.spec.recording
        row["verdicts_correct"] = r.verdicts_correct
    return row


def confusion(results: list[SessionResult], names: list[str]) -> list[list[int]]:
    """Rows = recognised structure, columns = true structure (the thesis's layout)."""
    idx = {n: i for i, n in enumerate(names)}
    m = [[0] * len(names) for _ in names]
    for r in results:
        if r.final_guess in idx and r.spec.truth in idx:
            m[idx[r.final_guess]][idx[r.spec.truth]] += 1
    return m


def summarize(results: list[SessionResult]) -> dict:
    """The summary.json figures of an experiment."""
    ms = [m for r in results for m in connection_matches(r)]
    devs = [m["t_detected"] - m["t_true"] for m in ms if m["t_detected"] is not None]
    dist = timing_distribution(results)
    out = {
        "sessions": len(results),
        "connections_total": len(ms),
        "connections_detected": sum(1 for m in ms if m["t_detected"] is not None),
        "connections_within_1s": dist["1"]["within"],
        "connections_never": dist["1"]["never"],
        "within_rate": {T: round(c["within"] / max(1, len(ms)), 4) for T, c in dist.items()},
        "timing_distribution": dist,
        "mean_deviation_s": round(float(np.mean(devs)), 3) if devs else None,
        "mean_abs_deviation_s": round(float(np.mean(np.abs(devs))), 3) if devs else None,
        "false_completions": sum(r.false_completions for r in results),
        "mean_completion_s": round(float(np.mean([r.completion_true for r in results if r.completion_true])), 2)
        if results else None,
        "wall_seconds": round(sum(r.seconds for r in results), 1),
        "frames": sum(r.frames for r in results),
    }
    exp = results[0].spec.experiment if results else None
    if exp == "guess":
        out["guess_correct"] = sum(1 for r in results if r.final_guess == r.spec.truth)
        out["guess_accuracy"] = round(out["guess_correct"] / max(1, len(results)), 4)
    if exp == "learning":
        out["sentences_correct"] = sum(1 for r in results if r.verdicts_correct)
    return out
