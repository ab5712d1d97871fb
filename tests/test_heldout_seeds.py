"""Held-out discipline (issue 11): seed lists, refusal of tuning seeds for reported figures, the "lost" rule, and
the held-out benchmark's covering design."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest

from tracker.evaluation.pose_errors import LOST_FRAMES, PoseErrorLog, lost_runs
from tracker.evaluation.seeds import check_seeds, parse_seeds
from tracker.geometry.parts import PartSpec

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from benchmarks import bench_heldout  # noqa: E402


def test_parse_seeds_ranges_and_lists():
    assert parse_seeds("100-103") == [100, 101, 102, 103]
    assert parse_seeds("100,105") == [100, 105]
    assert parse_seeds(" 100-101, 120,100 ") == [100, 101, 120]
    for bad in ("", "a", "5-3", "100-x", "-1"):
        with pytest.raises(ValueError):
            parse_seeds(bad)


def test_tuning_seeds_are_refused_for_reporting_and_required_for_development():
    assert check_seeds([100, 115]) == [100, 115]
    with pytest.raises(ValueError, match="tuning seeds"):
        check_seeds([100, 3])
    with pytest.raises(ValueError, match="≥ 100"):
        check_seeds([50])
    assert check_seeds([0, 4], dev=True) == [0, 4]
    with pytest.raises(ValueError, match="development"):
        check_seeds([0, 100], dev=True)


def test_lost_runs_count_long_runs_of_large_error_only():
    log = PoseErrorLog([PartSpec("a", box=(0.036, 0.036, 0.036)), PartSpec("b", box=(0.036, 0.036, 0.036))])
    n = LOST_FRAMES
    # a: n frames 6 cm off (lost), n - 1 frames 40° off (too short), 2n frames 40° off (lost), with good gaps
    big_r = math.radians(40)
    segments = [(0.001, 0.0, 5), (0.06, 0.0, n), (0.001, 0.0, 3), (0.001, big_r, n - 1), (0.001, 0.0, 3),
                (0.001, big_r, 2 * n), (0.001, 0.0, 2)]
    log.translation["a"] = [t for t, _, k in segments for _ in range(k)]
    log.rotation["a"] = [r for _, r, k in segments for _ in range(k)]
    # b: errors just under both limits all the time
    log.translation["b"] = [0.049] * (3 * n)
    log.rotation["b"] = [math.radians(29.0)] * (3 * n)
    assert lost_runs(log) == {"a": 2, "b": 0}


def test_bench_heldout_design_covers_every_pair_and_refuses_tuning_seeds(capsys):
    bench_heldout.check_design()
    with pytest.raises(ValueError, match="speed 2.0"):
        bench_heldout.check_design([d for d in bench_heldout.DESIGN if not (d[1] == "none" and d[3] == 2.0)])
    assert bench_heldout.main(["--seeds", "0-4", "--no-write"]) == 2
    assert "tuning seeds" in capsys.readouterr().err
    assert bench_heldout.main(["--dev", "--seeds", "100", "--no-write"]) == 2
    assert "development" in capsys.readouterr().err


def test_bench_heldout_changes_settings_only_in_development_runs(capsys):
    assert bench_heldout.parse_overrides(["blob_follow_overlap=true", "carry_radius=0.1", "velocity_model=constant"]) \
        == {"blob_follow_overlap": True, "carry_radius": 0.1, "velocity_model": "constant"}
    with pytest.raises(ValueError, match="KEY=VALUE"):
        bench_heldout.parse_overrides(["carry_radius"])
    assert bench_heldout.main(["--set", "carry_radius=0.1", "--no-write"]) == 2  # a reported run: default preset
    assert "--dev" in capsys.readouterr().err
    assert bench_heldout.main(["--dev", "--set", "no_such_setting=1", "--no-write"]) == 2
    assert "no_such_setting" in capsys.readouterr().err


def test_tracker_benchmarks_refuse_tuning_seeds_unless_dev(capsys):
    from benchmarks import bench_moving_camera, bench_tracker

    assert bench_tracker.main(["--seed", "0", "--no-write"]) == 2
    assert "tuning seeds" in capsys.readouterr().err
    assert bench_tracker.main(["--seeds", "1,2", "--no-write"]) == 2
    assert "tuning seeds" in capsys.readouterr().err
    assert bench_moving_camera.main(["--seed", "3", "--no-write"]) == 2
    assert "tuning seeds" in capsys.readouterr().err
    assert bench_moving_camera.main(["--dev", "--seed", "100", "--no-write"]) == 2
    assert "development" in capsys.readouterr().err


def test_bench_heldout_pairs_a_changed_setting_on_the_same_frames_only_in_development_runs(capsys):
    """``--pair`` runs a second tracker with a changed setting beside ours on the same frames (tuning only); with a
    setting that changes nothing the two give the same figures, and the bad part-frames are counted."""
    assert bench_heldout.main(["--pair", "carry_keep_unseen=0.3", "--no-write"]) == 2
    assert bench_heldout.main(["--no-icp", "--no-write"]) == 2
    assert bench_heldout.main(["--dev", "--pair", "no_such_setting=1", "--no-write"]) == 2
    capsys.readouterr()
    # static scene, no hand: a hand-carry setting cannot change anything
    assert bench_heldout.main(["--dev", "--no-icp", "--sessions", "1", "--frames", "6",
                               "--pair", "carry_keep_unseen=0"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines() if x.startswith("{")]
    session, overall = lines[0], lines[-1]
    assert session["pair_settings"] == {"carry_keep_unseen": 0}
    assert session["icp_backend"] is None and "icp" not in session
    assert session["ours"]["t_mean_all_mm"] == session["pair"]["t_mean_all_mm"] < 3.0
    assert overall["ours"]["bad_part_frames"] == overall["pair"]["bad_part_frames"] == 0
