"""Camera pose from resting parts (odometry/part_landmarks.py)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from tracker.geometry.pose import Pose
from tracker.odometry.part_landmarks import PartLandmarkOdometry


def _camera(i: int) -> Pose:
    """A swaying camera: its pose in the world (the first camera frame) at frame ``i``."""
    rv = np.radians([0.8 * np.sin(i / 7.0), 0.6 * np.sin(i / 5.0), 0.3 * np.sin(i / 9.0)])
    t = [0.02 * np.sin(i / 6.0), 0.01 * np.sin(i / 4.0), 0.015 * (1 - np.cos(i / 8.0))]
    return Pose.from_rt(Rotation.from_rotvec(rv).as_matrix(), np.asarray(t))


def test_camera_poses_from_resting_parts_while_a_hand_moves_one_of_them():
    """Four parts rest; from frame 20 to 40 a hand slides 'red' away (10 cm), then it rests again. The camera poses
    come out exact (the moved part is outvoted, then taken back as a landmark at its new place)."""
    rng = np.random.default_rng(0)
    world = {n: Pose.from_rt(Rotation.random(random_state=k).as_matrix(), rng.uniform([-0.15, -0.1, 0.55],
                                                                                     [0.15, 0.1, 0.7]))
             for k, n in enumerate(("red", "green", "blue", "yellow"))}
    corners = np.array([[x, y, z] for x in (-0.018, 0.018) for y in (-0.018, 0.018) for z in (-0.018, 0.018)])
    centres = {n: corners for n in world}
    odo = PartLandmarkOdometry()
    for i in range(80):
        cam = _camera(i)
        parts = dict(world)
        if i >= 20:
            s = min(i - 20, 20) / 20.0
            parts["red"] = Pose.from_rt(world["red"].R, world["red"].t + [0.1 * s, 0.0, 0.0])
        observed = {n: cam.inverse() @ W for n, W in parts.items()}  # part → camera
        est = odo.update(observed, centres)
        assert np.linalg.norm(est.t - cam.t) < 1e-6, (i, est.t, cam.t)
        assert np.degrees(est.rotation_error(cam)) < 1e-4
    assert "red" in odo.world  # resting again at its new place: a landmark again
    assert np.linalg.norm(odo.world["red"].t - (world["red"].t + [0.1, 0.0, 0.0])) < 1e-6


def test_the_last_pose_is_kept_without_agreeing_landmarks():
    odo = PartLandmarkOdometry()
    centres = {"a": np.zeros((1, 3)), "b": np.zeros((1, 3))}
    odo.update({"a": Pose.from_rt(np.eye(3), [0.0, 0.0, 0.6]), "b": Pose.from_rt(np.eye(3), [0.1, 0.0, 0.6])},
               centres)
    # the two landmarks now disagree by 5 cm: no consensus, the camera stays where it was
    est = odo.update({"a": Pose.from_rt(np.eye(3), [0.05, 0.0, 0.6]), "b": Pose.from_rt(np.eye(3), [0.1, 0.0, 0.6])},
                     centres)
    assert odo.used == 0 and np.allclose(est.t, 0.0)

