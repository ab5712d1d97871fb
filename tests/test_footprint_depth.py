"""Depth over a hidden part's footprint (filter/footprint_depth.py): covered by a hand, or left (the table shows where
it was), and the carry that starts at once when it has left (``carry_left_table``). Constructed depth frames."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.filter import hidden_parts
from tracker.filter.footprint_depth import classify_footprint, covered, left_place
from tracker.filter.hand_carry import Shadow
from tracker.filter.particle_filter import MultiObjectTracker
from tracker.filter.tracker_config import TrackerConfig
from tracker.geometry.box_renderer import render_box_depth
from tracker.geometry.camera import Intrinsics
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose

INTR = Intrinsics.default(160, 120)
TABLE_Z = 0.7
PLANE = (np.array([0.0, 0.0, -1.0]), TABLE_Z)  # a fronto-parallel table 0.7 m away, normal towards the camera
REST = Pose([0.0, 0.0, TABLE_Z - 0.018], [0, 0, 0, 1])  # a 36 mm cube standing on it


def _tracker(**over) -> MultiObjectTracker:
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=50, **over)
    tr = MultiObjectTracker([PartSpec.cube("red", "red")], INTR, cfg, seed=0)
    tr.initialize({"red": REST})
    return tr


def _table() -> np.ndarray:
    return np.full((INTR.height, INTR.width), TABLE_Z, np.float32)


def _with_cube(depth: np.ndarray, pose: Pose = REST) -> np.ndarray:
    cube = render_box_depth(INTR, [pose], [(0.036, 0.036, 0.036)])
    return np.where(np.isfinite(cube), np.minimum(cube, depth), depth).astype(np.float32)


def _columns(tr) -> tuple[int, int]:
    """Image columns of the cube's silhouette at its estimate (end-exclusive)."""
    u = INTR.project(tr.corners[0] @ tr.estimates["red"].R.T + tr.estimates["red"].t)[:, 0]
    return int(np.floor(u.min())), int(np.ceil(u.max())) + 1


def test_the_cube_in_place_is_shown_a_hand_over_it_covers_it_the_bare_table_means_it_left():
    tr = _tracker()
    fp = classify_footprint(tr, 0, _with_cube(_table()), PLANE)
    assert fp.shown > 0.9 and fp.table == 0.0 and not left_place(fp, 0.2) and not covered(fp)
    hand = np.full_like(_table(), 0.62)  # a hand 6 cm above the cube's top over all of it
    fp = classify_footprint(tr, 0, hand, PLANE)
    assert fp.nearer > 0.9 and covered(fp) and not left_place(fp, 0.2)
    fp = classify_footprint(tr, 0, _table(), PLANE)
    assert fp.table > 0.9 and left_place(fp, 0.2) and not covered(fp)
    # fractions of the silhouette's pixels: what has depth adds up
    assert np.isclose(fp.nearer + fp.shown + fp.behind + fp.missing, 1.0)


def test_picked_up_under_the_hand_the_table_showing_on_part_of_the_footprint_is_enough():
    """The hand and the lifted cube still cover the left part of the footprint; the right part shows the table; most
    of the rest has no depth (the hand's projector shadow): the cube has left all the same. With the cube still on
    the table under that hand, the same uncovered strip shows the cube's top, not the table: not left."""
    tr = _tracker()
    u0, u1 = _columns(tr)
    cut = u0 + (u1 - u0) * 2 // 3
    lifted = _table()
    lifted[:, :cut] = 0.62
    lifted[:, u0 + (u1 - u0) // 3 : cut] = np.nan  # the projector's shadow
    fp = classify_footprint(tr, 0, lifted, PLANE)
    assert fp.missing > 0.2 and 0.2 < fp.of_valid(fp.table) < 0.6
    assert left_place(fp, 0.2) and not left_place(fp, 0.8)
    resting = _with_cube(_table())
    resting[:, :cut] = lifted[:, :cut]
    fp = classify_footprint(tr, 0, resting, PLANE)
    assert fp.table == 0.0 and fp.shown > 0.2 and not left_place(fp, 0.2)


def test_depth_behind_the_part_but_off_the_table_plane_is_not_the_table():
    tr = _tracker()
    hole = np.full_like(_table(), TABLE_Z + 0.05)  # seen through to something 5 cm below the table plane
    fp = classify_footprint(tr, 0, hole, PLANE)
    assert fp.behind > 0.9 and fp.table == 0.0 and not left_place(fp, 0.2)
    assert classify_footprint(tr, 0, _table(), None).table == 0.0  # without a table plane nothing is the table


def test_too_few_pixels_with_depth_decide_nothing_and_a_mesh_part_is_not_classified():
    tr = _tracker()
    depth = np.full_like(_table(), np.nan)
    u0, u1 = _columns(tr)
    depth[:, u0 : u0 + 2] = TABLE_Z  # a sliver of table, the rest without depth
    fp = classify_footprint(tr, 0, depth, PLANE)
    assert fp.valid < 0.25 and not left_place(fp, 0.2)
    assert not left_place(None, 0.2) and not covered(None)
    tr.meshes[0] = object()  # any mesh: only boxes are classified
    assert classify_footprint(tr, 0, _table(), PLANE) is None


def _fist(shift_m: float) -> np.ndarray:
    """The table with a fist over the resting cube's place, moved ``shift_m`` to the right: a dome of 3 cm radius whose
    top is 5 cm above the cube (round, so that its registration is constrained in every direction)."""
    depth = _table()
    vv, uu = np.mgrid[0 : INTR.height, 0 : INTR.width]
    z0 = 0.62
    x = (uu - INTR.cx) * z0 / INTR.fx - (REST.t[0] + shift_m)
    y = (vv - INTR.cy) * z0 / INTR.fy - REST.t[1]
    r2 = (x**2 + y**2) / 0.03**2
    dome = z0 + 0.03 * r2
    return np.where(r2 < 1.0, dome, depth).astype(np.float32)


def _hidden_pickup(tr, shadow: bool) -> np.ndarray:
    """Last frame: a fist over the resting cube; this frame: the fist has moved 3 cm to the right with the cube, the
    table showing on the left of its old footprint. Prepares the tracker's last-frame state, returns this frame."""
    prev = _fist(0.0)
    tr.visibility[:] = 0.0  # hidden last frame
    tr._blob_off, tr._pre_reseed = np.zeros(1, bool), {}  # the colour stage's per-frame results: no blob
    tr._carry._prev_depth = prev
    if shadow:
        pts = tr._carry._points(prev, REST.t, tr.config.carry_radius, PLANE, [])
        tr._carry.shadows[0] = Shadow(pts, np.array([0.004, 0.0, 0.0]), np.array([0.004, 0.0, 0.0]))
    return _fist(0.03)


@pytest.mark.parametrize("shadow", [True, False])
@pytest.mark.parametrize("on", [True, False])
def test_a_hidden_cube_whose_place_shows_the_table_is_carried_at_once(on, shadow):
    """The rest prior held the estimate still, so the motion test says "resting"; the table showing where the cube
    was starts its carry this frame (``carry_left_table``), from its shadow carry when it has one, else from last
    frame's hand points registered to this frame's: the cube goes right with the hand. Off: it stays put, uncarried."""
    tr = _tracker(carry_left_table=0.2 if on else 0.0, carry_shadow=True, carry_revealed_fraction=0.5,
                  revealed_surface=True, carry_start_register=True)
    now = _hidden_pickup(tr, shadow)
    fp = classify_footprint(tr, 0, now, PLANE)
    assert left_place(fp, 0.2) and not hidden_parts.revealed(tr, 0, now)  # the fist still covers part of it
    hidden_parts.follow_hands(tr, now, np.zeros(1, bool), PLANE, {})
    moved = tr.estimates["red"].t - REST.t
    if on:
        assert tr._carry.carried[0]
        assert 0.025 < moved[0] < 0.045 and abs(moved[1]) < 0.005, moved  # taken right, with the fist (3 cm)
    else:
        assert not tr._carry.carried[0]
        assert np.linalg.norm(moved) < 1e-9
