"""A resting part snatched while hidden (filter/hidden_parts.py): the see-through test and the shadow carry."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.filter import hidden_parts
from tracker.filter.hand_carry import Shadow
from tracker.filter.particle_filter import MultiObjectTracker
from tracker.filter.tracker_config import TrackerConfig
from tracker.geometry.box_renderer import render_box_depth
from tracker.geometry.camera import Intrinsics
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose

INTR = Intrinsics.default(160, 120)
REST = Pose([0.0, 0.0, 0.682], [0, 0, 0, 1])  # a 36 mm cube standing on a fronto-parallel table 0.7 m away


def _tracker(**over) -> MultiObjectTracker:
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=50, carry_revealed_fraction=0.5, **over)
    tr = MultiObjectTracker([PartSpec.cube("red", "red")], INTR, cfg, seed=0)
    tr.initialize({"red": REST})
    return tr


@pytest.mark.parametrize("surface", [True, False])
def test_the_bare_table_where_a_resting_cube_was_reveals_it_gone(surface):
    """The table right under a resting box is never 1.5 cm behind the box's far side (its bottom face lies on it):
    only the test against the rendered surface sees that the cube has gone. The cube itself in the depth (or a hand
    above it) reveals nothing either way."""
    tr = _tracker(revealed_surface=surface)
    table = np.full((INTR.height, INTR.width), 0.7, np.float32)
    assert hidden_parts.revealed(tr, 0, table) == surface
    assert np.allclose(tr.center[0], 0.0)
    cube = render_box_depth(INTR, [REST], [tuple(2 * tr.half[0])])
    with_cube = np.where(np.isfinite(cube), np.minimum(cube, table), table).astype(np.float32)
    assert not hidden_parts.revealed(tr, 0, with_cube)
    hand = np.full_like(table, 0.62)
    assert not hidden_parts.revealed(tr, 0, hand)


def test_a_revealed_part_goes_where_its_shadow_says_and_is_carried_on():
    tr = _tracker(carry_shadow=True)
    turn = Pose.from_rotvec([0.0, 0.0, 0.2], [0.0, 0.0, 0.0]).R
    move = np.array([0.08, -0.01, -0.03])
    patch = np.random.default_rng(0).normal(REST.t + move, 0.01, (50, 3))
    pos = np.array([REST.t])
    tr._carry.shadows[0] = Shadow(patch, turn, move - turn @ REST.t + REST.t, np.zeros(3), np.zeros(3))
    assert hidden_parts.take_shadow(tr, 0, pos)
    est = tr.estimates["red"]
    assert np.allclose(est.t, REST.t + move, atol=1e-9) and np.allclose(est.R, turn, atol=1e-9)
    assert np.allclose(pos[0], REST.t + move) and tr._carry.carried[0]
    # a shadow that went nowhere (the hand stayed over the part) is no sign of where it went
    tr2 = _tracker(carry_shadow=True)
    tr2._carry.shadows[0] = Shadow(patch, np.eye(3), np.array([0.01, 0.0, 0.0]), np.zeros(3), np.zeros(3))
    assert not hidden_parts.take_shadow(tr2, 0, np.array([REST.t]))
    assert np.allclose(tr2.estimates["red"].t, REST.t)
