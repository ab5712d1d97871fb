"""Rest prior on rotation (filter/hidden_parts.py, ``rest_prior_rotation``): a hidden resting part keeps the rotation
of its last good view, carried along with the camera's motion."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation


@pytest.mark.parametrize("hold", [True, False])
def test_a_hidden_resting_cube_keeps_the_rotation_of_its_last_good_view(hold):
    """A cube seen well at rest (its anchor), then covered by a hand: the last refinement before it vanished turned
    it 6° (pulled by the hand's depth), and the camera then turned 2°. With the rotation hold its particles take the
    anchor's rotation as the camera moved it; without it they keep the wrong turn."""
    from tracker.filter.camera_motion import apply_camera_motion
    from tracker.filter.frame_context import FrameContext
    from tracker.filter.hidden_parts import hold_hidden_parts
    from tracker.filter.particle_filter import MultiObjectTracker
    from tracker.filter.tracker_config import TrackerConfig
    from tracker.frame import Frame
    from tracker.geometry.camera import Intrinsics
    from tracker.geometry.parts import PartSpec
    from tracker.geometry.pose import Pose

    intr = Intrinsics.default(640, 480)
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=30, carry_follow=False, rest_prior_rotation=hold)
    tr = MultiObjectTracker([PartSpec.cube("red", "red")], intr, cfg, seed=0)
    good = Pose([0.0, 0.05, 0.6], Rotation.from_euler("z", 20, degrees=True).as_quat())
    tr.initialize({"red": good})
    turned = Rotation.from_euler("xz", [4.0, 4.5], degrees=True).as_matrix() @ good.R  # about 6 degrees off
    tr.R[:, 0] = turned
    tr.estimates["red"] = Pose.from_rt(turned, good.t)
    tr.visibility = np.array([0.02])  # covered by the hand
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("y", 2.0, degrees=True).as_matrix()
    T[:3, 3] = [0.01, 0.0, 0.0]
    apply_camera_motion(tr, T)
    frame = Frame(1, 1 / 30, np.zeros((480, 640, 3), np.uint8), np.full((480, 640), np.nan, np.float32), intr)
    ctx = FrameContext(frame=frame, table=None, table_plane=None, t0=0.0)
    hold_hidden_parts(tr, ctx, {}, np.zeros(1, bool))
    assert tr._rest_on[0]
    expected = T[:3, :3] @ good.R
    err = [np.degrees(Rotation.from_matrix(R @ expected.T).magnitude()) for R in tr.R[:, 0]]
    if hold:
        assert max(err) < 1e-6
    else:
        assert min(err) > 5.0
