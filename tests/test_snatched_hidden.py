"""A resting part snatched while hidden (filter/hidden_parts.py): the see-through test and the shadow carry."""

from __future__ import annotations

import numpy as np
import pytest
from carry_runs import SNATCH_FRAMES, snatch_under_arm

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
    move = np.array([0.08, -0.01, -0.03])
    patch = np.random.default_rng(0).normal(REST.t + move, 0.01, (50, 3))
    pos = np.array([REST.t])
    tr._carry.shadows[0] = Shadow(patch, move, np.zeros(3))
    assert hidden_parts.take_shadow(tr, 0, pos)
    est = tr.estimates["red"]
    assert np.allclose(est.t, REST.t + move, atol=1e-9) and np.allclose(est.R, REST.R, atol=1e-9)
    assert np.allclose(pos[0], REST.t + move) and tr._carry.carried[0]
    # a shadow that went nowhere (the hand stayed over the part) is no sign of where it went
    tr2 = _tracker(carry_shadow=True)
    tr2._carry.shadows[0] = Shadow(patch, np.array([0.01, 0.0, 0.0]), np.zeros(3))
    assert not hidden_parts.take_shadow(tr2, 0, np.array([REST.t]))
    assert np.allclose(tr2.estimates["red"].t, REST.t)


def test_upright_turns_a_box_by_the_least_angle_onto_a_face_and_keeps_its_turn_about_the_normal():
    from scipy.spatial.transform import Rotation

    normal = np.array([0.0, -0.8, -0.6])
    for seed in range(5):
        R = Rotation.random(random_state=seed).as_matrix()
        U = hidden_parts.upright(R, normal)
        assert np.isclose(np.abs(U.T @ normal).max(), 1.0)  # a body axis along the normal: lying on a face
        # the least turn: no other face-down rotation of the box is nearer (the 6 faces × turns about the normal)
        least = np.degrees(Rotation.from_matrix(U @ R.T).magnitude())
        assert least <= 54.8  # a box axis is always within arccos(1/√3) of the normal
    tilted = Rotation.from_rotvec(0.3 * normal).as_matrix() @ Rotation.from_rotvec([0.1, 0.0, 0.0]).as_matrix()
    up = hidden_parts.upright(tilted, normal)
    # what it removed is a pure tilt: no turn about the normal
    assert abs(Rotation.from_matrix(up @ tilted.T).as_rotvec() @ normal) < 1e-9


@pytest.mark.parametrize("upright", [True, False])
def test_a_hidden_cube_set_down_on_the_table_lies_on_a_face(upright):
    """A cube resting unseen (no depth over it, only its colour blob) whose last estimate was tilted 12° by a hand's
    registration noise: with ``table_upright`` it is set flat on the table, its 20° turn about the table normal kept;
    without it the tilt stays."""
    from scipy.spatial.transform import Rotation

    from tracker.frame import Frame
    from tracker.perception.color_detection import ColorDetection

    tr = _tracker(table_upright=upright)
    plane = (np.array([0.0, 0.0, -1.0]), 0.7)
    yaw = Rotation.from_euler("z", 20, degrees=True)
    tilt = Rotation.from_euler("x", 12, degrees=True)
    tr.initialize({"red": Pose(REST.t, (tilt * yaw).as_quat())})
    tr._rest_R[0] = (tilt * yaw).as_matrix()
    corners = REST.transform_points(np.array([[-0.018, -0.018, -0.018], [0.018, 0.018, -0.018]]))
    uv = INTR.project(corners)
    (u0, v0), (u1, v1) = np.floor(uv[0]).astype(int), np.ceil(uv[1]).astype(int)
    depth = np.full((INTR.height, INTR.width), 0.7, np.float32)
    depth[v0 - 3 : v1 + 3, u0 - 3 : u1 + 3] = np.nan
    box = np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]], np.int32)
    blob = ColorDetection("red", ((u0 + u1) / 2, (v0 + v1) / 2), 1.0, float((u1 - u0) * (v1 - v0)), None, box)
    for i in range(5):
        st = tr.step(Frame(i, i / 30, np.zeros((INTR.height, INTR.width, 3), np.uint8), depth, INTR), {"red": blob},
                     plane)
    R = st.poses["red"].R
    tilt_deg = np.degrees(np.arccos(np.clip(np.abs(R.T @ plane[0]).max(), -1.0, 1.0)))
    if upright:
        assert tilt_deg < 0.5, tilt_deg
        yaw_err = np.degrees(abs(Rotation.from_matrix(R @ yaw.as_matrix().T).as_rotvec()[2]))
        assert yaw_err < 1.0, yaw_err
    else:
        assert tilt_deg > 8.0, tilt_deg


@pytest.mark.parametrize("lift, tilt_deg, carried, turned", [
    (0.0, 12.0, False, True),  # resting on the table, tilted: laid on its face
    (0.03, 12.0, False, False),  # 3 cm above the table: in the air, left as it is
    (0.0, 30.0, False, False),  # tilted beyond resting_upright_deg (20°): not a resting box's error
    (0.0, 12.0, True, False),  # carried: the hand holds it as it is
])
def test_a_visible_box_resting_on_the_table_is_turned_onto_a_face(lift, tilt_deg, carried, turned):
    """``resting_upright_deg``: after the refinement, a box whose lowest point is on the table and whose estimate is
    tilted by less than the bound is turned upright about its centre (its turn about the table normal, its centre
    and its particles' spread around it kept); in the air, tilted farther or carried it is not."""
    from scipy.spatial.transform import Rotation

    from tracker.filter.particle_filter import TrackerState

    tr = _tracker(resting_upright_deg=20.0)
    plane = (np.array([0.0, 0.0, -1.0]), 0.7)
    rot = Rotation.from_euler("x", tilt_deg, degrees=True) * Rotation.from_euler("z", 25, degrees=True)
    # the tilted cube's lowest corner on (or `lift` above) the table: its centre at 0.7 - lift - the half diagonal
    low = float((np.abs(rot.as_matrix().T @ plane[0]) * 0.018).sum())
    pose = Pose([0.0, 0.0, 0.7 - lift - low], rot.as_quat())
    tr.initialize({"red": pose})
    if carried:
        tr._carry.start(0, np.zeros((10, 3)))
    spread = tr.p[:, 0] - pose.t
    state = TrackerState(index=0, timestamp=0.0, poses={"red": pose}, particles={}, weights=np.ones(50) / 50)
    hidden_parts.upright_resting(tr, state, plane)
    est = tr.estimates["red"]
    tilt_after = np.degrees(np.arccos(np.clip(np.abs(est.R.T @ plane[0]).max(), -1.0, 1.0)))
    if turned:
        assert tilt_after < 1e-6 and state.poses["red"] is est
        assert np.linalg.norm(est.t - pose.t) < 1e-9  # a cube's origin is its centre: it turns in place
        yaw = np.degrees(abs(Rotation.from_matrix(est.R @ Rotation.from_euler("z", 25, degrees=True).as_matrix().T)
                             .as_rotvec()[2]))
        assert yaw < 1.0, yaw
        np.testing.assert_allclose(np.linalg.norm(tr.p[:, 0] - est.t, axis=1), np.linalg.norm(spread, axis=1))
    else:
        assert abs(tilt_after - tilt_deg) < 1e-6 and state.poses["red"] is pose



SNATCH_SEEDS = (5, 6, 7)
"""Tracker seeds of the snatch tests: how early the take is seen varies with small changes of the poses (after the
take, worst errors with carry_shadow_take_m 6-12 mm over these seeds, 56 mm with the refinement's early end;
with carry_left_table alone 11-40 mm; without either 67-70 mm; session 30), so the bounds hold for medians over
three seeds."""


def _worst_after_take(**kw) -> list[float]:
    """Yellow's worst translation error (m) from frame 252 (after the take) per tracker seed of SNATCH_SEEDS; asserts
    that before the take (resting and hidden) every seed holds it within 8 mm (3-5 mm)."""
    out = []
    for seed in SNATCH_SEEDS:
        errs, _ = snatch_under_arm(tracker_seed=seed, **kw)
        assert errs[SNATCH_FRAMES < 247].max() < 0.008, (seed, errs[SNATCH_FRAMES < 247].max())
        out.append(float(errs[SNATCH_FRAMES >= 252].max()))
    return out


def test_a_hand_that_moved_far_from_a_hidden_part_it_covered_has_taken_it():
    """carry_shadow_take_m: the hand's shadow carry over the hidden cube has followed the hand 3 cm while the cube's
    place stays under the arm (never seen through): the cube is taken to be in that hand and carried (within 2 cm
    from then on); without it the cube stays where it was while the hand carries it 6 cm away (medians over
    SNATCH_SEEDS)."""
    taken, left = _worst_after_take(take_m=0.03), _worst_after_take()
    assert np.median(taken) < 0.02, taken
    assert np.median(left) > 0.04, left


def test_the_table_showing_where_a_hidden_part_was_starts_its_carry():
    """carry_left_table (default): the same snatch without carry_shadow_take_m and without the hand tracker: the table
    shows on part of the cube's place as the hand takes it, and the cube is carried from then on: within 5 cm (11-40
    mm) and at least 2 cm nearer than left behind without it (medians over SNATCH_SEEDS)."""
    carried, left = np.array(_worst_after_take(left_table=0.2)), np.array(_worst_after_take())
    assert np.median(carried) < 0.05, carried
    assert np.median(left - carried) > 0.02, (left, carried)
