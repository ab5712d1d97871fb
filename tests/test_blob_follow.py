"""Blob follow (filter/blob_follow.py): a part seen in colour but not in depth moves with its colour blob."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.filter.tracker_config import TrackerConfig
from tracker.geometry.camera import Intrinsics

PLANE = (np.array([0.0, 0.0, -1.0]), 0.7)  # a fronto-parallel table 0.7 m away: height = 0.7 - z
HALF = 0.018  # the default cube's half side (m)


def _bbox(box: np.ndarray) -> tuple[int, int, int, int]:
    """``(x, y, w, h)`` of a polygon (pixels), as the colour detector reports it."""
    x0, y0 = box.min(axis=0)
    x1, y1 = box.max(axis=0)
    return int(x0), int(y0), int(x1 - x0 + 1), int(y1 - y0 + 1)


def _run(follow: bool, area_jump: bool = False, overlap: bool = False,
         inside_px: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
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
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=100, blob_follow=follow,
                                                       blob_follow_overlap=overlap, blob_follow_inside_px=inside_px)
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
        blob = ColorDetection("red", ((u0 + u1) / 2, (v0 + v1) / 2), 1.0, float((u1 - u0) * (v1 - v0)), _bbox(box),
                              box)
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


def _shrinking(overlap: bool, inside_px: float = 0.0, keep_anchor: bool = False,
               anchors: list | None = None, inside_covered: bool = False) -> tuple[np.ndarray, int]:
    """A red cube rests at 0.682 m with no depth near it while something comes over it from the right: its blob
    loses 2 px of its right side per frame (at most a sixth of its area per frame, so the area test lets it through)
    for 12 frames. Returns the image position (u) of the estimate's centre minus the truth's, per frame, and the
    number of frames in which blob follow moved the part; ``anchors``, if given, gets the rest anchor's distance
    from the truth (m) after each frame."""
    from tracker.filter.particle_filter import MultiObjectTracker
    from tracker.frame import Frame
    from tracker.geometry.parts import PartSpec
    from tracker.geometry.pose import Pose
    from tracker.perception.color_detection import ColorDetection

    intr = Intrinsics.default(640, 480)
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=100, blob_follow_overlap=overlap,
                                                       blob_follow_inside_px=inside_px,
                                                       blob_follow_keep_anchor=keep_anchor,
                                                       blob_follow_inside_covered=inside_covered)
    tr = MultiObjectTracker([PartSpec.cube("red", "red")], intr, cfg, seed=0)
    truth = Pose([-0.02, 0.0, 0.682], [0, 0, 0, 1])
    tr.initialize({"red": truth})
    depth = np.full((480, 640), 0.7, np.float32)
    depth[100:380, 140:560] = np.nan
    corners = truth.transform_points(np.array([[-HALF, -HALF, -HALF], [HALF, HALF, -HALF]]))
    (u0, v0), (u1, v1) = np.round(intr.project(corners))
    true_u = intr.project(truth.t[None])[0, 0]
    off, followed = [], 0
    for i in range(12):
        right = u1 - 2 * i
        box = np.array([[u0, v0], [right, v0], [right, v1], [u0, v1]], np.int32)
        blob = ColorDetection("red", ((u0 + right) / 2, (v0 + v1) / 2), 1.0, float((right - u0) * (v1 - v0)),
                              _bbox(box), box)
        st = tr.step(Frame(i, i / 30, np.zeros((480, 640, 3), np.uint8), depth, intr), {"red": blob}, PLANE)
        off.append(intr.project(st.poses["red"].t[None])[0, 0] - true_u)
        followed += int(tr._blob_moved[0])
        if anchors is not None:
            anchors.append(float(np.linalg.norm(tr._rest_t[0] - truth.t)))
    return np.array(off), followed


def test_a_blob_that_only_shrinks_is_not_followed_with_the_outline_test():
    """A hand coming over a resting part moves its blob's centroid away from the hand: without the outline test
    blob follow drags the part along; with it the part stays put (the colour input's pull remains)."""
    dragged, n_dragged = _shrinking(False)
    held, n_held = _shrinking(True)
    assert n_dragged >= 8 and n_held == 0, (n_dragged, n_held)
    assert dragged[-1] < -10.0, dragged  # pixels: the centroid moved 11 px left and the part went with it
    assert np.abs(held).max() < 0.7 * np.abs(dragged).max(), (held, dragged)


def test_the_outline_test_still_follows_a_moving_blob():
    est, truth = _run(True, overlap=True)
    assert np.abs(est - truth)[5:].max() < 2.5


def test_a_blob_that_shrinks_inside_the_parts_footprint_is_not_followed():
    """``blob_follow_inside_px``: a blob that shrinks within the resting part's projected rectangle (a hand coming
    over it) does not move the part; without the setting blob follow drags it 10 px along."""
    dragged, n_dragged = _shrinking(False)
    held, n_held = _shrinking(False, inside_px=3.0)
    assert n_dragged >= 8 and n_held == 0, (n_dragged, n_held)
    assert dragged[-1] < -10.0, dragged
    assert np.abs(held).max() < 0.7 * np.abs(dragged).max(), (held, dragged)


def test_a_blob_that_leaves_the_parts_footprint_is_still_followed():
    """``blob_follow_inside_px``: a part sliding 4 mm a frame leaves its footprint, and blob follow keeps up."""
    est, truth = _run(True, inside_px=3.0)
    assert np.abs(est - truth)[5:].max() < 3.5


def test_a_dragged_resting_part_keeps_its_rest_anchor():
    """``blob_follow_keep_anchor``: blob follow still moves a resting part with its shrinking blob (a hand coming
    over it), but its rest anchor stays where the part was seen, so the rest prior can hold the hidden part there;
    without the setting the anchor is dragged along with it."""
    dragged_anchor: list[float] = []
    kept_anchor: list[float] = []
    _, n_dragged = _shrinking(False, anchors=dragged_anchor)
    _, n_kept = _shrinking(False, keep_anchor=True, anchors=kept_anchor)
    assert n_dragged >= 8 and n_kept >= 8, (n_dragged, n_kept)  # blob follow fires in both
    assert max(dragged_anchor) > 0.005, dragged_anchor  # metres: the anchor went with the drag
    assert max(kept_anchor) < 0.002, kept_anchor


def test_the_inside_test_gated_by_the_depth_holds_a_covered_part_and_follows_one_it_cannot_see_covered():
    """``blob_follow_inside_covered``: the footprint test stops blob follow only while the depth shows something over
    the part. With no depth over it (a projector shadow), nothing says a hand is there: the shrinking blob is
    followed as without the inside test. The gate itself: a hand 6 cm over the cube covers it; the cube itself, the
    bare table or no depth do not."""
    from types import SimpleNamespace

    from tracker.filter.blob_follow import covered_now
    from tracker.filter.particle_filter import MultiObjectTracker
    from tracker.geometry.parts import PartSpec
    from tracker.geometry.pose import Pose

    _, n_held = _shrinking(False, inside_px=3.0)
    _, n_gated = _shrinking(False, inside_px=3.0, inside_covered=True)
    assert n_held == 0 and n_gated >= 8, (n_held, n_gated)
    intr = Intrinsics.default(160, 120)
    tr = MultiObjectTracker([PartSpec.cube("red", "red")], intr, TrackerConfig.preset("default"), seed=0)
    tr.initialize({"red": Pose([0.0, 0.0, 0.682], [0, 0, 0, 1])})
    hand = np.full((120, 160), 0.62, np.float32)
    table = np.full((120, 160), 0.7, np.float32)
    cube = table.copy()
    cube[40:80, 50:110] = 0.664  # the cube's top face and around it (the footprint's pixels show its surface)
    none = np.full_like(hand, np.nan)
    for depth, want in ((hand, True), (table, False), (cube, False), (none, False), (None, False)):
        assert covered_now(tr, 0, SimpleNamespace(depth=depth, table_plane=PLANE)) == want
