"""A carried part the hand has put down is held where it was put (issue 11, ``carry_set_down_m``).

A hidden carried part follows the hand's depth points at the offset it had when the carry began; when that offset is
off by a centimetre the part rides a centimetre high, stops that high when the hand sets it down, and
``carry_release_on_lift``'s height test (lowest point within ``carry_min_height`` of the table) flickers, so the hand
rising takes the part along. Seen on tuning sessions (guess-2 sway seed 1, guidance-demo seed 2): the estimate stopped
9.7-10.3 mm above the table, then the fingers opening slid it 7 mm and the hand rising lifted it 30 mm (41.6 mm off
where the hand left it). The rule: a part that has been in the air, whose hand then stands still for two frames with
the part's lowest point within ``carry_set_down_m`` of the table, is moved onto the table and held there; the hand
rising lets go of it, the hand moving on along the table takes it along again.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_release_on_lift import EDGE, INTR, NORMAL, PLANE, RISE, SEEDS, cube_on_table, rise_gain, run, sequence

from tracker.filter.hidden_parts import held_where_put, lowest_height
from tracker.filter.particle_filter import MultiObjectTracker
from tracker.filter.tracker_config import TrackerConfig
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose

RIDING_HIGH = 0.009  # m: the carried estimate's height above the truth when the hand sets it down


def tracker(set_down_m: float) -> MultiObjectTracker:
    """A tracker whose red cube is carried through the air and now rides 9 mm above the table."""
    part = PartSpec.cube("red", "red", edge=EDGE)
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=50, carry_set_down_m=set_down_m)
    trk = MultiObjectTracker([part], INTR, cfg, seed=0)
    on_table = cube_on_table(0.0)
    trk.initialize({"red": Pose.from_rt(on_table.R, on_table.t + NORMAL * RIDING_HIGH)})
    trk._carry.was_in_air[0] = True
    return trk


def step(trk: MultiObjectTracker, move: np.ndarray) -> str:
    est = trk.estimates["red"]
    height = lowest_height(trk, 0, est.R, est.t, PLANE)
    return held_where_put(trk, 0, est.t, est.t + move, height, PLANE)


def height_mm(trk: MultiObjectTracker) -> float:
    est = trk.estimates["red"]
    return 1000.0 * lowest_height(trk, 0, est.R, est.t, PLANE)


ALONG = np.cross(NORMAL, [1.0, 0.0, 0.0])
ALONG /= np.linalg.norm(ALONG)  # a direction along the table top


def test_a_part_the_hand_stops_with_near_the_table_is_put_on_it_and_held_while_the_hand_opens():
    trk = tracker(0.02)
    assert abs(height_mm(trk) - 1000.0 * RIDING_HIGH) < 0.5
    assert step(trk, np.zeros(3)) == "follow"  # one still frame is not yet a set-down
    assert step(trk, 0.001 * ALONG) == "hold"
    assert abs(height_mm(trk)) < 0.2  # onto the table
    put = trk.estimates["red"].t.copy()
    for _ in range(3):  # the fingers opening: the registration reads a 2.5 mm slide per frame
        assert step(trk, 0.0025 * ALONG) == "hold"
    assert np.allclose(trk.estimates["red"].t, put)  # it stays where it was put
    assert step(trk, 0.005 * NORMAL) == "release"  # the hand rises from it: let go


def test_a_hand_that_moves_on_along_the_table_takes_the_part_along_again():
    trk = tracker(0.02)
    step(trk, np.zeros(3))
    assert step(trk, np.zeros(3)) == "hold"
    assert step(trk, 0.012 * ALONG) == "hold"
    assert step(trk, 0.012 * ALONG) == "follow"  # 24 mm along the table since: pushed, not let go
    assert not trk._carry.put_down[0]


@pytest.mark.parametrize("case", ["off", "never in the air", "too high", "hand moving"])
def test_no_set_down_without_every_condition(case):
    trk = tracker(0.0 if case == "off" else 0.02)
    if case == "never in the air":
        trk._carry.was_in_air[0] = False  # picked up from the table and not lifted yet
    if case == "too high":
        est = trk.estimates["red"]
        trk.estimates["red"] = Pose.from_rt(est.R, est.t + NORMAL * 0.015)  # 24 mm: held above the table
    move = 0.004 * ALONG if case == "hand moving" else np.zeros(3)
    before = height_mm(trk)
    assert [step(trk, move) for _ in range(4)] == ["follow"] * 4
    assert abs(height_mm(trk) - before) < 1e-6


def test_in_the_put_down_scene_the_rule_alone_keeps_the_part_where_the_hand_left_it():
    """The scene of test_release_on_lift (a hidden cube carried, held on the table, the hand rising 6 mm per frame):
    with carry_set_down_m and without carry_release_on_lift the cube stays put when the hand rises (within 1 mm,
    every seed of SEEDS), at least 3 mm less far up than without it (median)."""
    frames = sequence()
    put_down = RISE.start - 1
    gain = []
    for seed in SEEDS:
        with_rule, _ = run(frames, release_on_lift=0, set_down_m=0.02, tracker_seed=seed)
        without, _ = run(frames, release_on_lift=0, tracker_seed=seed)
        assert with_rule[RISE].max() < with_rule[put_down] + 1.0, (seed, with_rule[RISE])
        gain.append(rise_gain(with_rule, without))
    assert np.median(gain) > 3.0, gain


def test_in_a_simulated_carry_the_cube_put_down_is_held_nearer_the_truth():
    """The simulated carry of test_hand_carry (the default settings, a cube carried about 60 frames hidden and put down
    beside another): with the rule its worst error in the hand falls from 17.3 to 10.5 mm (the last frames of the
    carry, where the hand opens and rises), and it is found again once the hand has gone, as without."""
    from test_hand_carry import _carry_run

    on, hidden, carried, _ = _carry_run()
    off, _, _, _ = _carry_run(carry_set_down_m=0.0)
    assert carried > 30
    default = TrackerConfig.preset("default")
    assert default.carry_set_down_m > 0 and TrackerConfig().carry_set_down_m == 0
    assert default.carry_set_down_on_parts and not TrackerConfig().carry_set_down_on_parts
    # 4.6-8.9 mm on tracker seeds 5-7 and with the refinement's early end (session 30): 2 mm keeps a margin
    assert on[hidden].max() < off[hidden].max() - 0.002, (on[hidden].max(), off[hidden].max())
    assert on[-10:].mean() < 0.002 and off[-10:].mean() < 0.002


def test_a_part_put_on_top_of_another_is_put_down_on_its_top():
    """The same on a cube resting on the table: the carried cube riding 9 mm above the other's top is put down on it
    (surface_below), not pushed through it to the table; a cube beside the carried one is no support."""
    red, green = PartSpec.cube("red", "red", edge=EDGE), PartSpec.cube("green", "green", edge=EDGE)
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=50, carry_set_down_m=0.02,
                                                         carry_set_down_on_parts=True)
    for beside, expected_mm in ((0.0, 1000.0 * EDGE), (EDGE, 0.0)):
        trk = MultiObjectTracker([red, green], INTR, cfg, seed=0)
        below = cube_on_table(beside)
        above = cube_on_table(0.0)
        start_h = EDGE + RIDING_HIGH if beside == 0.0 else RIDING_HIGH
        trk.initialize({"red": Pose.from_rt(above.R, above.t + NORMAL * start_h), "green": below})
        trk._carry.was_in_air[0] = True
        step(trk, np.zeros(3))
        assert step(trk, np.zeros(3)) == "hold"
        assert abs(height_mm(trk) - expected_mm) < 0.3, (beside, height_mm(trk))
