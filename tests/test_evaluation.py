"""Evaluation: a tracked end-to-end guess session, a small evaluate subset producing summary.json, metrics."""

import json

from app.cli import main
from tracker.evaluation.metrics import classify
from tracker.evaluation.runner import run_session
from tracker.evaluation.sessions import guess_sessions, sessions_for


def test_session_lists_match_the_thesis_sizes():
    assert [len(sessions_for(e)) for e in ("guidance", "guess", "learning")] == [15, 16, 12]
    assert sorted({s.truth for s in guess_sessions()}) == ["L", "T-tower", "tower-with-wings"]


def test_classify_early_within_late_never():
    assert classify(10.0, 8.5, 1.0) == "early"
    assert classify(10.0, 10.9, 1.0) == "within"
    assert classify(10.0, 11.5, 1.0) == "late" and classify(10.0, 11.5, 2.0) == "within"
    assert classify(10.0, None, 4.0) == "never"


def test_tracked_guess_session_reaches_the_right_verdict():
    """End to end on TRACKED poses: simulator frames → colour detection → table → particle filter → guess mode."""
    spec = next(s for s in guess_sessions() if s.user == 2 and s.truth == "L")  # fast user
    # This session's first two connections are blue–yellow (only the L has it) and green–blue; stop after them.
    t_second = sorted(t for t, _, _ in run_session(spec, max_time=0.0).truth_events)[1]
    r = run_session(spec, poses="tracked", frame_step=2, n_particles=100, max_time=t_second + 1.5)
    assert r.final_guess == "L"
    assert r.false_completions == 0
    detected = {frozenset((a, b)) for _, a, b in r.detected_events}
    assert frozenset(("blue", "yellow")) in detected


def test_evaluate_subset_writes_summary(tmp_path, capsys):
    out = tmp_path / "ev"
    assert main(["evaluate", "guess", "--out", str(out), "--sessions", "1", "--poses", "groundtruth"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    for key in ("sessions", "connections_total", "connections_within_1s", "connections_never", "false_completions"):
        assert key in summary
    assert summary["sessions"] == 1 and summary["connections_total"] == 4
    assert summary["connections_within_1s"] == 4 and summary["false_completions"] == 0
    assert summary["guess_correct"] == 1 and summary["confusion"]["rows_recognised_cols_true"][0][0] == 1
    assert "| 1 | 1 | 1 | guess-1 |" in (out / "guess.md").read_text()
    assert (out / "guess_timing.png").stat().st_size > 0 and (out / "guess_confusion.png").stat().st_size > 0
    assert main(["evaluate", "--list"]) == 0 and "learning" in capsys.readouterr().out


def test_learning_session_on_groundtruth_verdicts_and_no_false_completion():
    spec = next(s for s in sessions_for("learning") if s.user == 2 and s.recording == 4)
    r = run_session(spec, poses="groundtruth", frame_step=2)
    assert r.verdicts_correct and r.false_completions == 0  # the swapped-word twin mode never completes
    assert len(r.detected_events) == 3


def test_evaluate_takes_simulator_seeds(tmp_path, capsys):
    out = tmp_path / "ev"
    assert main(["evaluate", "guess", "--out", str(out), "--sessions", "1", "--poses", "groundtruth",
                 "--seeds", "105"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["seeds"] == [105] and summary["sessions"] == 1
    assert summary["connections_total"] == 4  # the same structure (guess-1, T-tower), another random build
    assert main(["evaluate", "guess", "--out", str(out), "--seeds", "1-x"]) == 1
    assert "1-x" in capsys.readouterr().err
