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


def _snap(index: int, t: list[float], angle_deg: float = 0.0) -> Snapshot:
    half = np.radians(angle_deg) / 2.0
    q = np.array([0.0, np.sin(half), 0.0, np.cos(half)])
    rng = np.random.default_rng(index)
    return Snapshot(frame_index=index, time=index / 30.0, poses={"blue": Pose(np.array(t), q)},
                    particles={"blue": rng.normal(size=(200, 3)).astype(np.float32)})


def test_parts_move_in_the_scene_only_when_they_moved_visibly(scene):
    """A sub-millimetre change of the estimate sends nothing (the browser need not redraw); a visible one moves the
    box and its particles."""
    from app.scene import POSE_STEP_DEG, POSE_STEP_M

    scene.update(_snap(10, [0.0, 0.0, 0.7]), None)
    node, cloud = scene.part_nodes["blue"], scene.particle_nodes["blue"]
    shown_points = cloud.points.copy()
    scene.update(_snap(11, [0.4 * POSE_STEP_M, 0.0, 0.7], angle_deg=0.4 * POSE_STEP_DEG), None)
    assert np.allclose(node.position, [0.0, 0.0, 0.7]) and np.allclose(node.wxyz, [1, 0, 0, 0])
    assert np.array_equal(cloud.points, shown_points)  # particles go with the box: unchanged too
    scene.update(_snap(12, [3 * POSE_STEP_M, 0.0, 0.7]), None)
    assert np.allclose(node.position, [3 * POSE_STEP_M, 0.0, 0.7])
    assert not np.array_equal(cloud.points, shown_points)
    scene.update(_snap(13, [3 * POSE_STEP_M, 0.0, 0.7], angle_deg=3 * POSE_STEP_DEG), None)  # a visible turn alone
    assert np.degrees(2 * np.arccos(min(1.0, abs(node.wxyz[0])))) == pytest.approx(3 * POSE_STEP_DEG)


def test_depth_cloud_is_resent_only_when_the_depth_changed(scene):
    from app.scene import DEPTH_CHANGE_M, DEPTH_EVERY, DEPTH_POINTS
    from tracker.frame import Frame, Intrinsics

    intr = Intrinsics.default().scaled(0.25)
    depth = np.full((intr.height, intr.width), 0.7, np.float32)
    color = np.full((intr.height, intr.width, 3), 120, np.uint8)
    noisy = depth + np.random.default_rng(1).uniform(-0.4, 0.4, depth.shape).astype(np.float32) * DEPTH_CHANGE_M

    def show(d: np.ndarray) -> np.ndarray:
        for _ in range(DEPTH_EVERY):  # the cloud is considered on every DEPTH_EVERY-th update
            scene.update(Snapshot(frame_index=0, time=0.0), Frame(0, 0.0, color, d, intr))
        return scene.depth_cloud.points.copy()

    first = show(depth)
    assert 0.5 * DEPTH_POINTS <= len(first) <= 2 * DEPTH_POINTS
    assert np.array_equal(show(noisy), first)  # sensor noise below DEPTH_CHANGE_M: not resent
    moved = depth.copy()
    moved[: intr.height // 3] = 0.6  # a third of the table got closer (a hand, a part)
    assert not np.array_equal(show(moved), first)


def test_scene_is_light_to_draw(scene):
    """No shadows, no environment map, and the viewer's redraws capped: the messages every viewer gets."""
    from viser import _messages

    from app.scene import SCENE_RENDER_FPS

    sent = list(scene.server._websock_server._broadcast_buffer.message_from_id.values())
    lights = [m for m in sent if isinstance(m, _messages.EnableLightsMessage)]
    assert lights and lights[-1].cast_shadow is False
    env = [m for m in sent if isinstance(m, _messages.EnvironmentMapMessage)]
    assert env and env[-1].hdri_data is None
    scripts = [m.source for m in sent if isinstance(m, _messages.RunJavascriptMessage)]
    assert any(f"window.__sceneRenderCap = {SCENE_RENDER_FPS}" in s for s in scripts)


def test_scene_settings_reach_the_scene(tmp_path):
    """``scene_hz`` and ``scene_render_fps`` of the settings are what the server's scene uses."""
    from viser import _messages

    from app.scene import SCENE_HZ, SCENE_RENDER_FPS
    from app.server import AppState
    from app.settings import Settings

    assert Settings().scene_hz == SCENE_HZ and Settings().scene_render_fps == SCENE_RENDER_FPS  # one default
    state = AppState(Settings(database=str(tmp_path / "s.db"), viser_port=free_port(), autostart=False,
                              scene_hz=2.5, scene_render_fps=5.0))
    state.startup()
    try:
        assert state.scene_updater.max_hz == 2.5 and state.scene.render_fps == 5.0
        sent = state.scene.server._websock_server._broadcast_buffer.message_from_id.values()
        assert any("window.__sceneRenderCap = 5.0" in m.source for m in sent
                   if isinstance(m, _messages.RunJavascriptMessage))
    finally:
        state.shutdown()
