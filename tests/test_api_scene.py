"""The viser scene: handles follow a snapshot (part poses, particles, learning words, guidance ghost)."""

from __future__ import annotations

import socket

import numpy as np
import pytest

from app.scene import MAX_PARTICLES_SHOWN, Scene, ghost_target, word_labels
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose
from tracker.snapshot import Snapshot


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def scene():
    sc = Scene(host="127.0.0.1", port=free_port(), parts=[PartSpec.cube("red", "red"), PartSpec.cube("blue", "blue")])
    yield sc
    sc.stop()


def test_mode_state_readers():
    assert word_labels({"assignment": {"red": "Me", "blue": "<b>x</b>"}, "words": [{"word": "Me"}]}) == {
        "red": "Me",
        "blue": "<b>x</b>",
    }
    assert ghost_target({"next_step": None}) is None
    part, pose = ghost_target({"next_step": {"part": "blue", "target_pose": {"t": [0, 0, 1], "q": [0, 0, 0, 1]}}})
    assert part == "blue" and np.allclose(pose.t, [0, 0, 1])


def test_update_moves_handles_in_place(scene):
    red_node = scene.part_nodes["red"]
    table_to_camera = Pose(np.array([0.0, 0.1, 0.8]), np.array([0.0, 0.0, 0.0, 1.0]))
    snap = Snapshot(
        frame_index=3,
        time=0.1,
        poses={"red": Pose(np.array([0.05, 0.0, 0.8]), np.array([0.0, 0.0, 0.0, 1.0]))},
        particles={"red": np.random.default_rng(0).normal(size=(1000, 3)).astype(np.float32)},
        mode="learning",
        mode_state={"assignment": {"red": "gusta"}},
        table={"normal": [0, -1, 0], "offset": 0.1, "table_to_camera": table_to_camera.to_dict()},
    )
    scene.update(snap, None)
    assert scene.part_nodes["red"] is red_node  # same handle, moved
    assert np.allclose(red_node.position, [0.05, 0.0, 0.8]) and red_node.visible
    assert not scene.part_nodes["blue"].visible  # no pose yet
    cloud = scene.particle_nodes["red"].points
    assert cloud.dtype == np.float32 and len(cloud) == MAX_PARTICLES_SHOWN < 1000  # a fixed subsample of the particles
    assert scene.label_nodes["red"].text == "gusta" and scene.label_nodes["red"].visible
    assert np.allclose(scene.camera_node.position, [0.0, -0.1, -0.8])  # camera seen from the table frame
    assert not scene.ghost.visible

    snap.mode = "guidance"
    snap.mode_state = {"next_step": {"part": "blue", "target_pose": {"t": [0.09, 0.0, 0.8], "q": [0, 0, 0, 1]}}}
    scene.update(snap, None)
    assert scene.ghost.visible and np.allclose(scene.ghost.position, [0.09, 0.0, 0.8])
    assert tuple(scene.ghost.color) == (35, 70, 200)
    assert not scene.label_nodes["red"].visible  # words only in learning mode


def test_camera_frustum_and_path_follow_the_odometry(scene):
    assert not scene.frustum.visible  # no odometry pose yet
    for i in range(3):
        table_to_camera = Pose(np.array([0.01 * i, 0.1, 0.8]), np.array([0.0, 0.0, 0.0, 1.0]))
        snap = Snapshot(frame_index=i, time=i / 30.0, camera_pose=Pose(np.array([-0.01 * i, 0.0, 0.0])),
                        camera_pose_ok=i != 2,
                        table={"normal": [0, -1, 0], "offset": 0.1, "table_to_camera": table_to_camera.to_dict()})
        scene.update(snap, None)
    assert scene.frustum.visible and scene.camera_path.visible
    path = scene.camera_path.points
    assert path.shape == (3, 3) and np.allclose(path[:, 0], [0.0, -0.01, -0.02])  # camera positions, table frame
    assert tuple(scene.frustum.color) == (230, 120, 30)  # the last pose was extrapolated
    d = snap.to_dict()
    assert d["camera_pose"]["ok"] is False and np.allclose(d["camera_pose"]["t"], [-0.02, 0.0, 0.0])


def test_hands_are_drawn_at_their_positions_with_what_they_hold(scene):
    hand = {"id": 1, "box": [10, 20, 60, 90], "score": 0.9, "velocity": [0.0, 0.0], "touching": [], "holding": ["red"],
            "text": "holding the red cube", "position": [0.02, -0.01, 0.7]}
    scene.update(Snapshot(frame_index=0, time=0.0, hands=[hand, {**hand, "id": 2, "position": None}]), None)
    assert scene.hand_nodes[0].visible and np.allclose(scene.hand_nodes[0].position, [0.02, -0.01, 0.7])
    assert scene.hand_labels[0].text == "holding the red cube" and scene.hand_labels[0].visible
    assert not scene.hand_nodes[1].visible  # no depth, no 3-D place
    scene.update(Snapshot(frame_index=1, time=0.03), None)
    assert not scene.hand_nodes[0].visible and not scene.hand_labels[0].visible
