"""Contact alignment (tracker/refine/contact_align.py, ``contact_align_deg``): a half-seen resting cube touching a
well-seen one face to face takes faces parallel to its neighbour's."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from tracker.filter.motion_model import rotvec_to_matrix
from tracker.filter.tracker_config import TrackerConfig
from tracker.geometry.camera import Intrinsics
from tracker.refine.contact_align import align_contacts, face_contact, nearest_parallel

HALF = np.full(3, 0.018)  # the default cube's half side (m)


def _turn(deg: float, axis=(0.0, 0.0, 1.0)) -> np.ndarray:
    return rotvec_to_matrix(np.radians(deg) * np.asarray(axis, np.float64)[None])[0]


def test_face_contact_of_two_stacked_cubes_and_not_of_apart_ones():
    R_b = _turn(30.0, (1.0, 0.0, 0.0))
    c_b = np.array([0.0, 0.0, 0.6])
    up = R_b[:, 1]  # one of b's axes
    assert face_contact(R_b @ _turn(8.0, (0, 1, 0)), c_b + 0.036 * up, HALF, R_b, c_b, HALF)
    assert not face_contact(R_b, c_b + 0.050 * up, HALF, R_b, c_b, HALF)  # 14 mm apart
    assert not face_contact(R_b, c_b + 0.036 * up + 0.04 * R_b[:, 0], HALF, R_b, c_b, HALF)  # beside, not on it


def test_nearest_parallel_undoes_a_small_turn_up_to_the_cube_symmetries():
    R_b = _turn(25.0, (1.0, 1.0, 0.0) / np.sqrt(2.0))
    R_a = R_b @ _turn(90.0, (0, 0, 1)) @ _turn(11.0, (0, 1, 0))  # a quarter turn (a symmetry) plus 11 deg
    R_new, angle = nearest_parallel(R_a, R_b)
    assert np.degrees(angle) == pytest.approx(11.0, abs=1e-6)
    np.testing.assert_allclose(R_new, R_b @ _turn(90.0, (0, 0, 1)), atol=1e-9)


def _scene(contact_align_deg: float, turn_deg: float, gap: float = 0.036):
    """Two cubes, ``blue`` resting on the table and ``red`` on top of it (centres ``gap`` apart along the table
    normal), red's estimate turned ``turn_deg`` about the normal; blue's refinement matched 400 depth points,
    red's 150. Returns red's rotation error (deg) against blue's axes after :func:`align_contacts`, and the names
    turned."""
    from tracker.filter.particle_filter import MultiObjectTracker
    from tracker.geometry.parts import PartSpec
    from tracker.geometry.pose import Pose
    from tracker.refine.dense_depth import RefineResult

    intr = Intrinsics.default(640, 480)
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=50, contact_align_deg=contact_align_deg)
    tr = MultiObjectTracker([PartSpec.cube("blue", "blue"), PartSpec.cube("red", "red")], intr, cfg, seed=0)
    tilt = _turn(40.0, (1.0, 0.0, 0.0))  # the camera looks down on the table at 40 deg
    blue = Pose.from_rt(tilt, np.array([0.0, 0.0, 0.6]))
    normal = -tilt[:, 1]
    red = Pose.from_rt(_turn(turn_deg, normal) @ tilt, blue.t + gap * normal)
    tr.initialize({"blue": blue, "red": red})
    tr._blob_moved = np.zeros(2, bool)
    ok = dict(healthy=True, n_model=500, valid_fraction=0.8, median_residual=0.001)
    tr._refiner.last = [RefineResult(blue.R, blue.t, n_valid=400, **ok), RefineResult(red.R, red.t, n_valid=150, **ok)]
    state = SimpleNamespace(poses={"blue": blue, "red": red}, particles={})
    turned = align_contacts(tr, state)
    _, angle = nearest_parallel(state.poses["red"].R, blue.R)
    centre_moved = np.linalg.norm(state.poses["red"].t - red.t)  # the cube's centre is its origin
    return np.degrees(angle), turned, centre_moved, tr


def test_a_half_seen_cube_on_a_well_seen_one_takes_its_neighbours_axes():
    err, turned, moved, tr = _scene(20.0, 9.0)
    assert turned == ["red"]
    assert err < 1e-6
    assert moved < 1e-9  # turned about its centre
    red = tr.names.index("red")
    _, particle_angle = nearest_parallel(tr.R[0, red], tr.estimates["blue"].R)
    assert np.degrees(particle_angle) < 3.0  # its particles turned with it (they scatter about the estimate)


@pytest.mark.parametrize("setting, turn, gap", [(0.0, 9.0, 0.036), (20.0, 30.0, 0.036), (20.0, 9.0, 0.05)])
def test_no_alignment_when_off_for_a_large_turn_or_without_contact(setting, turn, gap):
    err, turned, _, _ = _scene(setting, turn, gap)
    assert turned == []
    assert err == pytest.approx(turn, abs=1e-6)
