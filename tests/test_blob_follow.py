"""Blob follow (filter/blob_follow.py): a part seen in colour but not in depth moves with its colour blob."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.filter.tracker_config import TrackerConfig
from tracker.geometry.camera import Intrinsics

PLANE = (np.array([0.0, 0.0, -1.0]), 0.7)  # a fronto-parallel table 0.7 m away: height = 0.7 - z
HALF = 0.018  # the default cube's half side (m)


def _run(follow: bool, area_jump: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """A red cube slides 4 mm per frame to the right, 20 frames, at 0.682 m, with no depth anywhere near it (as
    in a hand's projector shadow); only its colour blob is seen, the same size every frame (or, with
    ``area_jump``, alternately full and a third, as a changing occlusion would make it). Returns the estimated and
    true image positions (u) of the cube's centre per frame."""
    from tracker.filter.particle_filter import MultiObjectTracker
    from tracker.frame import Frame
    from tracker.geometry.parts import PartSpec
    from tracker.geometry.pose import Pose
    from tracker.perception.color_detection import ColorDetection

    intr = Intrinsics.default(640, 480)
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=100, blob_follow=follow)
    tr = MultiObjectTracker([PartSpec.cube("red", "red")], intr, cfg, seed=0)
    start = Pose([-0.02, 0.0, 0.682], [0, 0, 0, 1])
    tr.initialize({"red": start})
    depth = np.full((480, 640), 0.7, np.float32)
    depth[100:380, 140:560] = np.nan  # no depth over the whole path (and around it)
    est_u, true_u = [], []
    for i in range(20):
        truth = Pose(start.t + [0.004 * i, 0.0, 0.0], [0, 0, 0, 1])
        corners = truth.transform_points(np.array([[-HALF, -HALF, -HALF], [HALF, HALF, -HALF]]))
        uv = intr.project(corners)
        (u0, v0), (u1, v1) = uv[0], uv[1]
        if area_jump and i % 2:
            u1 = u0 + (u1 - u0) / 3.0  # only the left third shows
        box = np.round([[u0, v0], [u1, v0], [u1, v1], [u0, v1]]).astype(np.int32)
        blob = ColorDetection("red", ((u0 + u1) / 2, (v0 + v1) / 2), 1.0, float((u1 - u0) * (v1 - v0)), None, box)
        st = tr.step(Frame(i, i / 30, np.zeros((480, 640, 3), np.uint8), depth, intr), {"red": blob}, PLANE)
        est_u.append(intr.project(st.poses["red"].t[None])[0, 0])
        true_u.append(intr.project(truth.t[None])[0, 0])
    return np.array(est_u), np.array(true_u)


@pytest.mark.parametrize("follow", [True, False])
def test_a_part_without_depth_moves_with_its_blob(follow):
    est, truth = _run(follow)
    lag = np.abs(est - truth)[5:]
    travelled = truth[-1] - truth[0]
    assert travelled > 5.0  # pixels: the cube really moves in the image
    if follow:
        assert lag.max() < 2.5, lag  # pixels (the blob corners are whole pixels)
    else:  # the colour input alone pulls it along, but behind
        assert np.median(lag) > 4.0, lag


def test_blob_follow_ignores_a_blob_whose_area_jumps():
    """A centroid that moves because the visible part of the blob changed is no motion of the part."""
    with_follow, truth = _run(True, area_jump=True)
    without, _ = _run(False, area_jump=True)
    assert np.ptp(truth) > 40.0
    np.testing.assert_array_equal(with_follow, without)
