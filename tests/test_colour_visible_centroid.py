"""Colour input against the expected visible region (filter/colour_input.py, ``color_visible_centroid``) and rest
anchors of moving parts (filter/hidden_parts.py, ``rest_anchor_moving``)."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation


def _tracker(**overrides):
    from tracker.filter.particle_filter import MultiObjectTracker
    from tracker.filter.tracker_config import TrackerConfig
    from tracker.geometry.camera import Intrinsics
    from tracker.geometry.parts import PartSpec
    from tracker.geometry.pose import Pose

    intr = Intrinsics.default(640, 480)
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=30, **overrides)
    tr = MultiObjectTracker([PartSpec.cube("red", "red")], intr, cfg, seed=0)
    pose = Pose([0.02, 0.03, 0.6], Rotation.from_euler("z", 25, degrees=True).as_quat())
    tr.initialize({"red": pose})
    return tr, intr, pose


@pytest.mark.parametrize("visible_centroid", [True, False])
def test_a_cube_half_under_a_hand_is_not_pulled_toward_its_blob_centroid(visible_centroid):
    """The cube is exactly where the estimate says, but a hand 8 cm in front covers the right half of it: the blob
    is the left half, its centroid a quarter of the cube's width left of the centre. Compared with the expected
    visible region the colour input is (nearly) zero; compared with the projected centre it pulls the cube left
    by millimetres."""
    from tracker.filter.colour_input import control_inputs
    from tracker.frame import Frame
    from tracker.geometry.box_renderer import render_box_depth

    tr, intr, pose = _tracker(color_visible_centroid=visible_centroid)
    depth = render_box_depth(intr, [pose], [tr.parts[0].box])
    sil = np.isfinite(depth)
    cols = np.nonzero(sil.any(axis=0))[0]
    mid = int(intr.project(pose.t[None])[0][0])
    hand = np.zeros_like(sil)
    hand[:, mid:cols.max() + 30] = True
    hand &= np.abs(np.arange(480)[:, None] - 240 - intr.fy * pose.t[1] / pose.t[2]) < 80
    depth = np.where(sil, depth, 0.8).astype(np.float32)
    depth[hand] = pose.t[2] - 0.08
    blob = sil & ~hand
    contours, _ = cv2.findContours(blob.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    contour = max(contours, key=cv2.contourArea).reshape(-1, 2)
    vv, uu = np.nonzero(blob)
    det = SimpleNamespace(center=(float(uu.mean()), float(vv.mean())), score=1.0, area=float(blob.sum()),
                          contour=contour)
    frame = Frame(1, 1 / 30, np.zeros((480, 640, 3), np.uint8), depth, intr)
    ctx = tr._begin_frame(frame, None)
    u, detected = control_inputs(tr, ctx, {"red": det})
    assert detected[0]
    lateral = float(np.hypot(u[0, 0], u[0, 1]))
    if visible_centroid:
        assert lateral < 1.0e-3
    else:
        assert lateral > 3.0e-3


@pytest.mark.parametrize("moving_anchor", [True, False])
def test_a_carried_cube_placed_by_the_depth_takes_its_refined_pose_as_rest_anchor(moving_anchor):
    """A cube in a hand, partly seen and placed by this frame's refinement, has moved 4 cm and turned 12° since it
    was last seen whole. Once hidden, the rest prior holds it at its anchor: with ``rest_anchor_moving`` that is
    the last placed pose, without it the stale pose from before the pick-up."""
    from tracker.filter.hidden_parts import update_moving_anchors
    from tracker.geometry.pose import Pose

    tr, _, pose = _tracker(rest_anchor_moving=moving_anchor)
    moved = Pose.from_rt(Rotation.from_euler("x", 12, degrees=True).as_matrix() @ pose.R, pose.t + [0.04, 0, -0.01])
    tr.estimates["red"] = moved
    tr._carry.start(0, np.zeros((20, 3)))
    tr._refiner.last[0] = SimpleNamespace(healthy=True)
    update_moving_anchors(tr)
    if moving_anchor:
        assert np.allclose(tr._rest_t[0], moved.t) and np.allclose(tr._rest_R[0], moved.R)
    else:
        assert np.allclose(tr._rest_t[0], pose.t) and np.allclose(tr._rest_R[0], pose.R)
    tr._refiner.last[0] = SimpleNamespace(healthy=False)  # not placed: the anchor is not touched
    tr.estimates["red"] = pose
    update_moving_anchors(tr)
    assert np.allclose(tr._rest_t[0], moved.t if moving_anchor else pose.t)


def test_the_visible_centroid_kernel_agrees_with_a_rendered_depth_image():
    """The numba sums of ``visible_centroid_bias`` against the same computation on a depth image rendered by
    ``render_box_depth`` (silhouette = finite pixels, sampled every 2nd pixel of the part's window), for a cube
    with a hand 6 cm in front of its lower half."""
    from tracker.filter import render
    from tracker.filter.colour_input import visible_centroid_bias
    from tracker.geometry.box_renderer import render_box_depth

    tr, intr, pose = _tracker()
    z = render_box_depth(intr, [pose], [tr.parts[0].box])
    depth = np.where(np.isfinite(z), z, 0.8).astype(np.float32)
    vc = int(intr.project(pose.t[None])[0][1])
    depth[vc:, :] = np.minimum(depth[vc:, :], pose.t[2] - 0.06)
    umin, umax, vmin, vmax = render.bbox(tr, 0, pose.t[None], pose.R[None])
    u0, u1, v0, v1 = int(np.floor(umin)), int(np.ceil(umax)) + 1, int(np.floor(vmin)), int(np.ceil(vmax)) + 1
    vv, uu = np.mgrid[v0:v1:2, u0:u1:2]
    zs, ds = z[vv, uu], depth[vv, uu]
    sil = np.isfinite(zs)
    seen = sil & ~(ds < zs - tr.config.color_occluded_margin)
    expected = [uu[seen].mean() - uu[sil].mean(), vv[seen].mean() - vv[sil].mean()]
    bias = visible_centroid_bias(tr, 0, depth)
    assert expected[1] < -3.0  # the upper half is what shows
    assert np.allclose(bias, expected, atol=1e-9)
