"""``track --hands`` (:class:`app.commands.track.TrackSession` with ``hands``): the hand tracker's touched parts reach
the part tracker, as in the pipeline with hands on."""

from __future__ import annotations

import pytest
from carry_runs import SNATCH_FRAMES, snatch_under_arm

from benchmarks import bench_heldout


def test_a_part_a_tracked_hand_touches_is_carried_with_it():
    """With the hand tracker the hand holding the hidden cube is seen to touch it: the cube is carried (within 2 cm
    after the grasp); without, it stays where it was while the hand takes it 7 cm away."""
    with_hands, touched = snatch_under_arm(hands=True)
    without, nothing = snatch_under_arm()
    after = SNATCH_FRAMES >= 252
    assert touched is not None and "yellow" in touched and nothing is None
    assert with_hands[after].max() < 0.02, with_hands[after].max()
    assert without[after].max() > 0.04, without[after].max()


def test_bench_heldout_compares_hands_at_the_products_odometry():
    """``bench_heldout.py --hands`` compares the tracker with and without the hand tracker, both with the camera
    odometry of the run (the product's default, fused): the session reports the arm without hands and the odometry's
    measured frames."""
    job = {"session": 7, "scenario": "guess-1", "motion": "handheld", "occlusion": 1.0, "speed": 1.5, "seed": 106,
           "frames": 4, "particles": 40, "odometry": bench_heldout.DEFAULT_MODE, "tracker_seed": 0, "overrides": {},
           "hands": True}
    res = bench_heldout.run_session(job)
    assert res["odometry"] == "fused" and "off" in res and res["hands"]
    assert res["odometry_measured"] == 4


@pytest.mark.parametrize("hands", [True, False])
def test_bench_heldout_session_reports_the_hand_arm(hands):
    """One short held-out session: with ``hands`` the report has the arm without hands beside ours and the hand
    tracker's CPU; without, neither."""
    job = {"session": 7, "scenario": "guess-1", "motion": "handheld", "occlusion": 1.0, "speed": 1.5, "seed": 106,
           "frames": 5, "particles": 60, "odometry": "off", "tracker_seed": 0, "overrides": {}, "hands": hands}
    res = bench_heldout.run_session(job)
    assert ("off" in res) == hands
    assert (res["hands_cpu_ms_median"] is not None) == hands
