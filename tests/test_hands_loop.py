"""Hands in the loop (hand-tracking spec §14.5–14.7): the pipeline's hand step on a simulated guidance session."""

from __future__ import annotations

import numpy as np

from tracker.geometry.camera import Intrinsics
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose
from tracker.hands.loop import HandLoop, box_part_depth
from tracker.pipeline import AssemblyPipeline
from tracker.sources.simulator import SimulatedTable


def test_part_depth_of_a_box_seen_face_on():
    intr = Intrinsics.default()
    cube = PartSpec.cube("red", "red")
    pose = Pose(np.array([0.0, 0.0, 0.5]))
    off = 0.03 * intr.fx / 0.482  # 3 cm off the centre on the front face: outside the 3.6 cm cube
    z = box_part_depth(cube, pose, intr, np.array([intr.cx - off, intr.cx, intr.cx + off]), np.array([intr.cy]))[0]
    assert np.isclose(z[1], 0.5 - cube.box[2] / 2, atol=1e-6)  # the front face
    assert np.isinf(z[0]) and np.isinf(z[2])


def test_simulated_hand_holding_a_part_shows_in_the_snapshot():
    """Seed 100 of guidance-demo: the hand grasps the red cube at about frame 70 and lifts it from frame 79. The
    snapshot's hand says it holds red (tracked poses: the hand carry follows the touched part) and the tracker keeps
    the red cube in the hand; before the hand arrives no hand is reported."""
    src = SimulatedTable("guidance-demo", seed=100, realtime=False)
    pipe = AssemblyPipeline(src.parts, src.intrinsics, mode="guidance", initial_poses=src.initial_poses, hands=True)
    holding, first_hand = [], None
    for i in range(92):
        snap = pipe.process(src.render(i))
        if snap.hands and first_hand is None:
            first_hand = i
        if any("red" in h["holding"] for h in snap.hands):
            holding.append(i)
            assert snap.hands[0]["text"] == "holding the red cube"
    assert first_hand is not None and first_hand > 30  # the hand enters after the first second
    assert holding and holding[-1] == 91  # still held at the end
    assert "red" in snap.carried
    lifted = src.groundtruth(91)["red"].t
    assert np.linalg.norm(snap.poses["red"].t - lifted) < 0.03  # the estimate went along with the hand
    assert snap.to_dict()["hands"][0]["holding"] == ["red"]
    assert "hands" in snap.timings and snap.timings["hands_cpu"] > 0


def test_table_and_part_pixels_are_not_hand():
    """On the hand-free first frame the whole wooden table (skin-coloured) and the cubes are excluded."""
    src = SimulatedTable("guidance-demo", seed=100, realtime=False)
    frame = src.render(0)
    from tracker.filter.frame_context import table_normal_offset
    from tracker.perception.table_plane import detect_table

    loop = HandLoop(src.parts, src.intrinsics)
    excl = loop.exclusion(frame.depth, table_normal_offset(detect_table(frame.depth, src.intrinsics)),
                          src.groundtruth(0))  # fmt: skip
    skin = loop.tracker.skin.mask(frame.color[::2, ::2]).astype(bool)
    assert skin.mean() > 0.5  # the table is skin-coloured
    assert (skin & ~excl).mean() < 0.01
    loop.perceive(frame.color, frame.depth, None, {})
    assert loop.touched_parts() is None and loop.occluder_mask() is None  # no hand: the gate stays open


def test_occluder_mask_covers_a_bare_forearm():
    """A skin palm with a bare forearm reaching the image border: H_k holds the forearm too (spec §14.5), not only
    the palm box's skin; with ``occluder_arm`` off only the palm's neighbourhood."""
    from tracker.hands.loop import HandLoopConfig
    from tracker.hands.tracker import HandTrackerConfig

    table = np.zeros((480, 640, 3), np.uint8) + np.uint8([120, 130, 140])
    img = table.copy()
    for t in np.linspace(0.0, 1.0, 600):  # forearm from the bottom-right corner up-left, 24 px wide
        x, y = int(639 - 300 * t), int(479 - 300 * t)
        img[max(y - 12, 0) : y + 12, max(x - 12, 0) : x + 12] = [215, 160, 130]
    img[130:190, 300:360] = [215, 160, 130]  # the palm at its far end
    masks = {}
    for arm in (True, False):
        cfg = HandLoopConfig(tracker=HandTrackerConfig(auto_init=False, seed=0), occluder_arm=arm)
        loop = HandLoop([], Intrinsics.default(), cfg)
        loop.perceive(table, None, None, {})
        loop.perceive(img, None, None, {})
        loop.tracker.start_track([300, 130, 360, 190])
        for _ in range(2):
            loop.perceive(img, None, None, {})
        masks[arm] = loop.occluder_mask()
    assert masks[True] is not None and masks[False] is not None
    assert masks[True][400, 560] and not masks[False][400, 560]  # a forearm pixel far from the palm
    assert masks[True][160, 330] and masks[False][160, 330]  # the palm in both
    assert not masks[True][50, 50]  # the table stays free


def _moving_palm(k: int) -> np.ndarray:
    """Frame k of a skin-coloured 60×60 palm moving 6 px per frame to the right over a grey table (0: no palm)."""
    img = np.zeros((480, 640, 3), np.uint8) + np.uint8([120, 130, 140])
    if k:
        x = 200 + 6 * k
        img[200:260, x : x + 60] = [215, 160, 130]
    return img


def _palm_loop(overlap: str) -> HandLoop:
    """A loop whose track is started by hand on the palm (the step runs in this process: ``worker`` "thread")."""
    from tracker.hands.loop import HandLoopConfig
    from tracker.hands.tracker import HandTrackerConfig

    cfg = HandLoopConfig(tracker=HandTrackerConfig(auto_init=False, seed=0), occluder_prior=True, occluder_arm=False,
                         overlap=overlap, worker="thread")  # fmt: skip
    loop = HandLoop([], Intrinsics.default(), cfg)
    loop.step(_moving_palm(0), None, None, {})
    loop.step(_moving_palm(1), None, None, {})
    loop.tracker.start_track([206, 200, 266, 260])
    return loop


def test_predicted_occluder_mask_moves_with_the_hand():
    """With overlap "lagged" the step also predicts H_k to the next frame by the hand's velocity: it covers the palm
    of frame k + 1 better than H_k does (the palm moves 6 px per frame, more than the 5 px dilation)."""
    loop = _palm_loop("lagged")
    for k in range(2, 9):
        loop.step(_moving_palm(k), None, None, {})
    assert loop.estimates and loop.estimates[0].state[4] > 3.0  # the track moves right
    now, predicted = loop.occluder, loop.next_occluder
    assert now is not None and predicted is not None and loop.tracker_occluders() is predicted
    palm_next = np.zeros((480, 640), bool)
    palm_next[200:260, 200 + 6 * 9 : 260 + 6 * 9] = True
    assert (palm_next & ~predicted).sum() < (palm_next & ~now).sum()
    assert predicted[230, 200 + 6 * 9 + 62] and not now[230, 200 + 6 * 9 + 62]  # ahead of the palm: predicted only


def test_hand_step_in_the_worker_thread_matches_the_callers_thread():
    """start / wait (the worker thread) give the same estimates and masks as running the step in the caller's
    thread; with "wait" the tracker's occluder prior is this frame's H_k; a bad frame's error comes out of wait."""
    import pytest

    threaded, inline = _palm_loop("wait"), _palm_loop("off")
    for k in range(2, 7):
        threaded.start(_moving_palm(k), None, None, {})
        inline.start(_moving_palm(k), None, None, {})
        threaded.wait()
        assert [e.box for e in threaded.estimates] == [e.box for e in inline.estimates]
        assert np.array_equal(threaded.tracker_occluders(), inline.occluder_mask())
    threaded.start(np.zeros((10, 10), np.uint8), None, None, {})
    with pytest.raises(ValueError):
        threaded.wait()
    threaded.close()


def test_pipeline_with_the_hand_step_in_a_thread_matches_the_sequential_one():
    """overlap "wait" (hand step in the worker thread, joined before the cube tracker) gives the same poses, hands and
    touched parts as "off" (all in the caller's thread) on guidance-demo seed 100 while the hand comes in."""
    from tracker.hands.loop import HandLoopConfig

    src = SimulatedTable("guidance-demo", seed=100, realtime=False)
    snaps = {}
    for overlap in ("off", "wait"):
        pipe = AssemblyPipeline(src.parts, src.intrinsics, mode="guidance", initial_poses=src.initial_poses, hands=True,
                                hand_config=HandLoopConfig(overlap=overlap))  # fmt: skip
        snaps[overlap] = [pipe.process(src.render(i)) for i in range(75)]
        pipe.hands.close()
    assert any(s.hands for s in snaps["off"])
    for a, b in zip(snaps["off"], snaps["wait"], strict=True):
        assert a.hands == b.hands and not a.errors and not b.errors
        for name, pose in a.poses.items():
            assert np.allclose(pose.t, b.poses[name].t, atol=1e-12)


def test_each_thread_has_its_own_optical_flow_instance():
    """OpenCV's DIS flow keeps working buffers in its instance: two hand steps in two threads (the hand loop's
    worker beside the caller, two stations) must not share one, or their flows mix. Same results in every thread."""
    import threading

    from tracker.hands import flow as hand_flow

    rng = np.random.default_rng(0)
    a = rng.integers(0, 255, (64, 80), np.uint8)
    b = np.roll(a, 2, axis=1)
    mine = hand_flow._dis(0)
    assert hand_flow._dis(0) is mine  # kept within a thread
    seen = {}

    def other():
        seen["dis"] = hand_flow._dis(0)
        seen["flow"] = hand_flow.flow(a, b)

    t = threading.Thread(target=other)
    t.start()
    t.join()
    assert seen["dis"] is not mine
    assert np.array_equal(seen["flow"], hand_flow.flow(a, b))
