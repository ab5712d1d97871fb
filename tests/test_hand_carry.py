"""Hand carry (filter/hand_carry.py): hidden parts in a hand follow the hand's depth points; resting ones stay."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from tracker.filter.hand_carry import HandCarry, register_rigid, register_translation
from tracker.filter.tracker_config import TrackerConfig
from tracker.geometry.camera import Intrinsics

CFG = TrackerConfig.preset("default")
PLANE = (np.array([0.0, 0.0, -1.0]), 0.7)  # a fronto-parallel table 0.7 m away: height = 0.7 - z


def test_register_translation_recovers_a_shift_and_caps_it():
    rng = np.random.default_rng(0)
    src = rng.uniform(-0.04, 0.04, (300, 3)) * [1.0, 1.0, 0.3]
    shift = np.array([0.012, -0.005, 0.003])
    dst = src + shift + rng.normal(0, 0.0005, src.shape)
    t = register_translation(src, dst, 20, 0.05)
    assert np.linalg.norm(t - shift) < 0.001, t
    capped = register_translation(src, dst, 20, 0.005)
    assert np.linalg.norm(capped) == pytest.approx(0.005)


def test_register_rigid_recovers_a_turn_and_a_shift_and_the_table_axis_variant_keeps_to_its_axis():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    # a hand-like patch: a palm slab with a thumb sticking out (not symmetric about any axis)
    palm = rng.uniform([-0.04, -0.03, -0.005], [0.04, 0.03, 0.005], (400, 3))
    thumb = rng.uniform([0.02, 0.03, -0.01], [0.035, 0.06, 0.01], (120, 3))
    src = np.vstack([palm, thumb]) + [0.0, 0.0, 0.6]
    c = src.mean(axis=0)
    turn = Rotation.from_euler("z", 6.0, degrees=True).as_matrix()
    shift = np.array([0.006, -0.004, 0.002])
    dst = (src - c) @ turn.T + c + shift + rng.normal(0, 0.0003, src.shape)
    w, t = register_rigid(src, dst, 15, 0.05, 0.3)
    assert abs(np.degrees(np.linalg.norm(w)) - 6.0) < 1.0 and abs(w[2]) > 0.9 * np.linalg.norm(w), np.degrees(w)
    assert np.linalg.norm(t - shift) < 0.0015, t
    w_axis, _ = register_rigid(src, dst, 15, 0.05, 0.3, axis=np.array([1.0, 0.0, 0.0]))
    assert np.allclose(w_axis[1:], 0.0, atol=1e-9)  # about the given axis only
    capped, _ = register_rigid(src, dst, 15, 0.05, np.radians(2.0))
    assert np.degrees(np.linalg.norm(capped)) == pytest.approx(2.0)


def _scene(intr: Intrinsics, hand_x: float, lower: float = 0.0) -> np.ndarray:
    """Depth of a table at 0.7 m under a rounded 12 x 6 cm 'hand' (a paraboloid cap, 0.60 m at its top, about
    0.63 m at its rim) spanning x = hand_x - 8 cm .. hand_x + 4 cm, ``lower`` m farther from the camera (nearer
    the table)."""
    depth = np.full((intr.height, intr.width), 0.7, np.float32)
    v, u = np.mgrid[0 : intr.height, 0 : intr.width]
    x = (u - intr.cx) / intr.fx * 0.62
    y = (v - intr.cy) / intr.fy * 0.62
    inside = (x > hand_x - 0.08) & (x < hand_x + 0.04) & (np.abs(y) < 0.03)
    depth[inside] = (0.60 + lower + 8.0 * ((x - hand_x + 0.02) ** 2 + y**2))[inside]
    return depth


def test_a_hidden_part_in_the_air_follows_the_hand_and_a_resting_one_stays():
    intr = Intrinsics.default(320, 240)
    carry = HandCarry(2, CFG, intr, np.array([0.031, 0.031]))
    # part 0 in the hand, 3 cm above the table; part 1 resting on the table (height 0) under the same hand
    pos = np.array([[0.0, 0.0, 0.65], [-0.055, 0.02, 0.682]])
    heights = np.array([0.03, 0.0])
    hidden = np.array([True, True])
    moved = []
    for k in range(6):
        depth = _scene(intr, 0.01 * k)
        rot, d = carry.update(depth, pos, hidden, ~hidden, heights, PLANE)
        new = np.einsum("kij,kj->ki", rot, pos) + d
        moved.append(new - pos)
        pos = new
    moved = np.array(moved)
    assert carry.carried.tolist() == [True, False]
    assert np.allclose(moved[1:, 0, 0], 0.01, atol=0.002), moved[:, 0]  # follows the hand 1 cm per frame
    assert np.allclose(moved[:, 1], 0.0)  # the resting part is not taken along
    # seen again: the carry ends
    carry.update(_scene(intr, 0.06), pos, np.array([False, True]), np.array([True, False]), heights, PLANE)
    assert carry.carried.tolist() == [False, False]


@pytest.mark.parametrize("shadow", [True, False])
def test_a_shadow_follows_the_hand_over_a_resting_part_but_not_its_reach_down(shadow):
    """A resting part hidden under a hand does not move with it, but with ``carry_shadow`` the hand's motion is
    followed as if it held the part: 5 cm after the hand went 5 cm. A hand coming down onto the part (towards the
    table) is reaching for it, not holding it: the shadow stays where the part is."""
    intr = Intrinsics.default(320, 240)
    cfg = CFG.with_overrides(carry_shadow=shadow)
    carry = HandCarry(1, cfg, intr, np.array([0.031]))
    pos = np.array([[-0.02, 0.0, 0.682]])
    heights, hidden = np.array([0.0]), np.array([True])
    for k in range(4):  # reaching down by 4 mm per frame
        rot, d = carry.update(_scene(intr, 0.0, lower=0.004 * k), pos, hidden, ~hidden, heights, PLANE)
        assert np.allclose(d, 0.0) and not carry.carried[0]
    if shadow:
        assert np.allclose(carry.shadows[0].t, 0.0)
    for k in range(1, 6):  # then sideways by 1 cm per frame
        rot, d = carry.update(_scene(intr, 0.01 * k, lower=0.012), pos, hidden, ~hidden, heights, PLANE)
        assert np.allclose(d, 0.0) and not carry.carried[0]  # the resting part itself stays
    if not shadow:
        assert carry.shadows[0] is None
        return
    sh = carry.shadows[0]
    assert np.allclose(sh.t, [0.05, 0.0, 0.0], atol=0.004), sh.t
    assert carry.take_shadow(0) is sh and carry.carried[0] and carry.shadows[0] is None  # carried on from there


@pytest.mark.parametrize("restart", [True, False])
def test_a_shadow_starts_again_when_the_hand_comes_back_over_a_resting_part(restart):
    """A hand covers a resting part, leaves it and comes back, then moves 5 cm: with ``carry_shadow_restart`` a new
    shadow follows it (5 cm), without it the shadow ended when the hand left and stays put."""
    intr = Intrinsics.default(320, 240)
    carry = HandCarry(1, CFG.with_overrides(carry_shadow=True, carry_shadow_restart=restart), intr,
                      np.array([0.031]))
    pos = np.array([[-0.02, 0.0, 0.682]])
    heights, hidden = np.array([0.0]), np.array([True])
    table_only = np.full((240, 320), 0.7, np.float32)
    for depth in [_scene(intr, 0.0, lower=0.012), table_only, _scene(intr, 0.0, lower=0.012)]:
        carry.update(depth, pos, hidden, ~hidden, heights, PLANE)
    for k in range(1, 6):
        rot, d = carry.update(_scene(intr, 0.01 * k, lower=0.012), pos, hidden, ~hidden, heights, PLANE)
        assert np.allclose(d, 0.0) and not carry.carried[0]  # the resting part itself stays
    sh = carry.shadows[0]
    if restart:
        assert sh.patch is not None and np.allclose(sh.t, [0.05, 0.0, 0.0], atol=0.004), sh.t
    else:
        assert sh.patch is None and np.allclose(sh.t, 0.0)


def test_the_carry_ends_when_the_hand_leaves():
    intr = Intrinsics.default(320, 240)
    carry = HandCarry(1, CFG, intr, np.array([0.031]))
    pos = np.array([[0.0, 0.0, 0.65]])
    carry.update(_scene(intr, 0.0), pos, np.array([True]), np.array([False]), np.array([0.03]), PLANE)
    assert carry.carried[0]
    table_only = np.full((240, 320), 0.7, np.float32)
    rot, d = carry.update(table_only, pos, np.array([True]), np.array([False]), np.array([0.03]), PLANE)
    assert not carry.carried[0] and np.allclose(d, 0.0) and np.allclose(rot, np.eye(3))


def _changed(overrides: dict) -> tuple:
    """The ``overrides`` that differ from the default preset, sorted (a run's cache key: runs asked for with the
    default's own values are the same run)."""
    return tuple(sorted((k, v) for k, v in overrides.items() if getattr(CFG, k) != v))


def _read_only(out: tuple) -> tuple:
    """``out`` with its arrays made read-only (shared between tests by a cache)."""
    for a in out:
        if isinstance(a, np.ndarray):
            a.flags.writeable = False
    return out


def _carry_run(tracker_seed: int = 5, **overrides) -> tuple[np.ndarray, np.ndarray, int, int]:
    """:func:`_carry_run_once`, computed once per test process for each seed and set of settings."""
    return _carry_run_cached(tracker_seed, _changed(overrides))


@cache
def _carry_run_cached(tracker_seed: int, overrides: tuple) -> tuple:
    return _read_only(_carry_run_once(tracker_seed, **dict(overrides)))


def _carry_run_once(tracker_seed: int = 5, **overrides) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Simulated guess-2 (tuning seed 1), frames 75-194, N = 120, default preset with ``overrides``: the hand lifts
    the blue cube, carries it ~25 cm completely hidden in its grasp and puts it down. Returns the blue cube's
    translation error per frame, whether it is completely hidden, in how many frames it was carried and in how many
    its coordinate pass was skipped."""
    from tracker.filter.particle_filter import MultiObjectTracker
    from tracker.perception.color_detection import ColorDetector
    from tracker.sources.simulator import SimulatedTable

    src = SimulatedTable("guess-2", seed=1, realtime=False)
    det = ColorDetector.from_parts(src.parts)
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=120, **overrides)
    tr = MultiObjectTracker(src.parts, src.intrinsics, cfg, seed=tracker_seed)
    blue = tr.names.index("blue")
    errs, hidden, carried, skipped = [], [], 0, 0
    for i in range(75, 195):
        f = src.render(i)
        g = f.meta["groundtruth"]
        if i == 75:
            tr.initialize(g["poses"])
        st = tr.step(f, det.detect(f.color), src.table_plane)
        errs.append(st.poses["blue"].translation_error(g["poses"]["blue"]))
        hidden.append(g["visible"]["blue"] == 0.0)
        carried += "blue" in st.carried
        skipped += int(tr._quiet_now[blue])
    return np.array(errs), np.array(hidden), carried, skipped


@pytest.mark.parametrize("follow", [True, False])
def test_tracker_keeps_a_cube_carried_inside_the_hand(follow):
    """With the hand carry the estimate of the cube carried out of sight (:func:`_carry_run`) stays with the hand;
    without it, it stays where the cube vanished. Both find the cube again once it is put down and visible
    (re-seeding)."""
    errs, hidden, carried, _ = _carry_run(carry_follow=follow)
    assert hidden.sum() > 30  # the script really hides the cube in the hand
    if follow:
        assert carried > 30
        assert errs[hidden].mean() < 0.06, errs[hidden].mean()
    else:
        assert carried == 0
        assert errs[hidden].mean() > 0.15, errs[hidden].mean()
    assert errs[-10:].mean() < 0.005, errs[-10:]


def test_a_part_hidden_in_the_moving_hand_skips_its_pass_and_keeps_closer_to_it():
    """carry_hidden_skip: while the hand carries the cube out of sight, its coordinate pass (which can only spread it
    over the hand's surface) is skipped and it moves with the hand's registration; its worst error in the hand is
    smaller, and it is found again once put down. (Run without carry_keep_unseen, on by default since session 15: with
    it the default's worst error in this carry is 31.5 mm, and skipping the pass no longer lowers it; nor with
    carry_anchor_start, on by default since session 16, with which the pass's worst error here is 18 mm; nor with
    carry_set_down_m, on by default since session 21, which holds the put-down cube on the table: the pass's worst
    error here 9.7 mm, skipping's 10.4; nor with carry_upright_air, on by default since session 24: the pass's worst
    error here 15.3 mm, skipping's 37.9; nor with reacquire_tilt_gain, on by default since session 26: the pass's
    worst error here 31.5 mm, skipping's 30.5.)"""
    old = {"carry_keep_unseen": 0.0, "carry_anchor_start": False, "blob_follow_inside_px": 0.0, "carry_set_down_m": 0.0,
           "carry_upright_air": False, "reacquire_tilt_gain": 0.0}
    with_pass, hidden, _, none_skipped = _carry_run(carry_hidden_skip=0.0, **old)
    skipping, _, _, skipped = _carry_run(carry_hidden_skip=0.1, **old)
    assert none_skipped == 0 and skipped > 30, (none_skipped, skipped)
    assert skipping[hidden].max() < 0.7 * with_pass[hidden].max(), (skipping[hidden].max(), with_pass[hidden].max())
    assert skipping[-10:].mean() < 0.005


@pytest.mark.parametrize("sigma", [0.003, 0.0])
def test_support_prior_sets_an_unseen_floating_part_down_on_the_table(sigma):
    """A red cube stands on a table 0.7 m away but its pixels have no depth (the sensor's shadow next to a hand);
    only its colour blob is seen. Started 2 cm too close to the camera (floating), the support prior brings its
    lowest point down to the table; without it nothing in the depth says where along the ray the cube is."""
    from tracker.filter.particle_filter import MultiObjectTracker
    from tracker.frame import Frame
    from tracker.geometry.parts import PartSpec
    from tracker.geometry.pose import Pose
    from tracker.perception.color_detection import ColorDetection

    intr = Intrinsics.default(160, 120)
    cfg = CFG.with_overrides(n_particles=100, support_prior_sigma=sigma)
    tr = MultiObjectTracker([PartSpec.cube("red", "red")], intr, cfg, seed=0)
    truth = Pose([0.0, 0.0, 0.682], [0, 0, 0, 1])  # resting: lowest face 0.7 - 0.682 - 0.018 = 0 above the table
    tr.initialize({"red": Pose([0.0, 0.0, 0.662], [0, 0, 0, 1])})
    corners = truth.transform_points(np.array([[-0.018, -0.018, -0.018], [0.018, 0.018, -0.018]]))
    uv = intr.project(corners)
    (u0, v0), (u1, v1) = np.floor(uv[0]).astype(int), np.ceil(uv[1]).astype(int)
    depth = np.full((120, 160), 0.7, np.float32)
    depth[v0 - 3 : v1 + 3, u0 - 3 : u1 + 3] = np.nan  # no depth on the cube (and a little around it)
    box = np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]], np.int32)
    blob = ColorDetection("red", ((u0 + u1) / 2, (v0 + v1) / 2), 1.0, float((u1 - u0) * (v1 - v0)), None, box)
    for i in range(30):
        st = tr.step(Frame(i, i / 30, np.zeros((120, 160, 3), np.uint8), depth, intr), {"red": blob}, PLANE)
    gap = abs(st.poses["red"].t[2] - truth.t[2])
    if sigma > 0:
        assert gap < 0.004, gap
    else:
        assert gap > 0.012, gap


@pytest.mark.parametrize("fallback", [True, False])
def test_a_turn_past_the_per_frame_cap_falls_back_to_the_translation(fallback):
    """A patch turned 15° in one frame against a 0.1 rad (5.7°) cap: without the fallback the registration
    returns the capped turn; with it the turn is taken as a failed registration and the translation-only
    registration is returned, with no turn."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    top = np.c_[rng.uniform(-0.03, 0.03, 400), rng.uniform(-0.02, 0.02, 400), np.zeros(400)]
    side = np.c_[rng.uniform(-0.03, 0.03, 300), np.full(300, 0.02), rng.uniform(0.0, 0.03, 300)]
    src = np.r_[top, side] + [0.0, 0.0, 0.6]
    c = src.mean(axis=0)
    dst = (src - c) @ Rotation.from_euler("z", 15, degrees=True).as_matrix().T + c + [0.004, 0.0, 0.0]
    w, t = register_rigid(src, dst, 8, 0.03, 0.1, None, None, fallback)
    if fallback:
        assert np.all(w == 0.0)
        assert np.allclose(t, register_translation(src, dst, 8, 0.03, None))
    else:
        assert np.linalg.norm(w) == pytest.approx(0.1)


@pytest.mark.parametrize("register_start", [True, False])
def test_a_carry_moves_the_part_with_the_hand_from_its_first_frame(register_start):
    """The part is seen in the hand in the first frame and hidden from the second, when the hand has moved 1 cm.
    With ``carry_start_register`` the carry registers the previous frame's hand points to this frame's and moves
    the part 1 cm at once; without it the part stands still for that frame and follows from the next."""
    intr = Intrinsics.default(320, 240)
    carry = HandCarry(1, CFG.with_overrides(carry_start_register=register_start), intr, np.array([0.031]))
    pos = np.array([[0.0, 0.0, 0.65]])
    heights = np.array([0.03])
    steps = []
    for k in range(3):
        hidden = np.array([k > 0])
        rot, d = carry.update(_scene(intr, 0.01 * k), pos, hidden, ~hidden, heights, PLANE)
        new = np.einsum("kij,kj->ki", rot, pos) + d
        steps.append(float(new[0, 0] - pos[0, 0]))
        pos = new
    assert steps[0] == 0.0 and carry.carried.tolist() == [True]
    assert steps[2] == pytest.approx(0.01, abs=0.002)
    assert steps[1] == (pytest.approx(0.01, abs=0.002) if register_start else 0.0)


def test_a_reseeded_part_jump_is_no_motion_for_the_carry_test():
    """A part put on its blob 5 cm away (re-seeding) has not moved: forgetting its positions keeps the jump out of
    the hand-carry motion test; the other part's motion still counts."""
    carry = HandCarry(2, CFG, Intrinsics.default(320, 240), np.array([0.031, 0.031]))
    carry.record(0.0, np.array([[0.0, 0.0, 0.6], [0.1, 0.0, 0.6]]))
    carry.record(0.1, np.array([[0.05, 0.0, 0.6], [0.13, 0.0, 0.6]]))
    assert carry.moved() == pytest.approx([0.05, 0.03])
    carry.forget(0)
    assert carry.moved() == pytest.approx([0.0, 0.03])
    carry.record(0.2, np.array([[0.05, 0.0, 0.6], [0.16, 0.0, 0.6]]))
    assert carry.moved() == pytest.approx([0.0, 0.06])


def test_the_keyframe_keeps_a_long_hidden_carry_from_drifting():
    """carry_keyframe: in the carry of :func:`_carry_run` (about 60 frames completely hidden) each frame's hand motion
    is corrected against the carry's first hand patch; the frame-to-frame registration's errors (0.3-2 mm a frame)
    no longer add up: the worst error in the hand is well below the chained registration's, and the cube is found
    again once put down. (Run without carry_keep_unseen, on by default since session 15: with it the
    default's worst error in this carry is 31.5 mm, and the keyframe no longer lowers it; nor with carry_anchor_start,
    on by default since session 16: 18 mm; nor with carry_keep_moving, on since session 17; nor with carry_set_down_m,
    on since session 21: the chained registration's worst error here 9.7 mm, the keyframe's 10.9; nor with
    carry_upright_air, on since session 24: 15.3 mm chained, 33.3 keyed.)"""
    old = {"carry_keep_unseen": 0.0, "carry_anchor_start": False, "blob_follow_inside_px": 0.0,
           "carry_keep_moving": 0.0, "carry_set_down_m": 0.0, "carry_upright_air": False}
    chained, hidden, _, _ = _carry_run(carry_keyframe=False, **old)
    keyed, _, carried, _ = _carry_run(carry_keyframe=True, **old)
    assert carried > 30
    assert keyed[hidden].max() < 0.6 * chained[hidden].max(), (keyed[hidden].max(), chained[hidden].max())
    assert keyed[hidden].mean() < chained[hidden].mean()
    assert keyed[-10:].mean() < 0.005


SLIVER_OFF = dict(carry_over_sliver=False, carry_sliver_particles=False, carry_lift_lookback=False)
"""The carry settings on by default since session 29, set off in the tests measured before them."""

FAST_CARRY = dict(carry_blob_depth=True, carry_keep_visibility=0.5, carry_reacquire_keep_turn=True,
                  carry_rest_prior=True, carry_keyframe=True, blob_follow_inside_px=0.0)
"""The settings for a part carried fast and partly seen (:func:`_fast_carry_run`), measured (session 13) without
blob_follow_inside_px (off; on for part of session 16; with it this run's worst error is 17 mm: the sliver the hand
takes stays inside the cube's footprint and is not followed in the frame it is picked up)."""


def _fast_carry_run(tracker_seed: int = 5, **overrides) -> tuple[np.ndarray, np.ndarray]:
    """Simulated learning-5 with a swaying camera, speed 2, occlusion 1.5 (tuning seed 3), frames 60-100, tracked
    from the true poses at frame 60, default preset with ``overrides``: a hand takes the orange cube and carries it
    about 3 cm a frame, mostly toward the camera, 10-50 % of it in view. Returns its translation error (m) and
    rotation error (deg, cube symmetry) per frame. Run without carry_keep_moving (on by default since session 17; with
    it and FAST_CARRY the worst rotation error here is 15.6 degrees) and without carry_upright_air (on by default since
    session 24; with it and FAST_CARRY the worst error here is 22.5 mm, 7.0 degrees) and without reacquire_tilt_gain
    (on by default since session 26; with it and FAST_CARRY the worst error here is 22.7 mm, 7.2 degrees) and without
    carry_over_sliver, carry_sliver_particles and carry_lift_lookback (on by default since session 29; with them and
    FAST_CARRY the worst error here is 17.4 mm, 9.0 degrees)."""
    from tracker.filter.particle_filter import MultiObjectTracker
    from tracker.geometry.symmetry import symmetric_rotation_error, symmetry_group
    from tracker.perception.color_detection import ColorDetector
    from tracker.sources.simulator import SimOptions, SimulatedTable

    src = SimulatedTable("learning-5", seed=3, realtime=False, n_frames=101,
                         options=SimOptions(speed=2.0, occlusion=1.5, camera_motion="sway"))
    det = ColorDetector.from_parts(src.parts)
    cfg = TrackerConfig.preset("default").with_overrides(**{"carry_keep_moving": 0.0, "carry_upright_air": False,
                                                            "reacquire_tilt_gain": 0.0, **SLIVER_OFF, **overrides})
    tr = MultiObjectTracker(src.parts, src.intrinsics, cfg, seed=tracker_seed)
    group = symmetry_group(next(p for p in src.parts if p.name == "orange"))
    t_err, r_err = [], []
    for i in range(60, 101):
        f = src.render(i)
        truth = f.meta["groundtruth"]["poses"]
        if i == 60:
            tr.initialize(truth)
        est = tr.step(f, det.detect(f.color), src.table_plane).poses["orange"]
        t_err.append(est.translation_error(truth["orange"]))
        r_err.append(np.degrees(symmetric_rotation_error(est.R, truth["orange"].R, group)))
    return np.array(t_err), np.array(r_err)


FAST_SEEDS = (5, 6, 7)
"""Tracker seeds of :func:`test_a_fast_partly_seen_carry_follows_the_hand`. The worst frame of this carry changes
with the seed and with changes that move poses a little (session 30, worst translation / rotation error with
FAST_CARRY: seed 5 11 mm / 7°, 6 30 mm / 19°, 7 23 mm / 23° — a wrong face for 16 frames —, seed 5 with the
refinement's early end 40 mm / 7°; with the settings all off 23 / 34, 38 / 43, 18 / 8, 23 / 7): the test compares
the arms per seed and bounds medians over the three seeds."""


@cache
def _fast_carry_worst(tracker_seed: int, overrides: tuple) -> tuple[float, float]:
    """Worst translation (m) and rotation (deg) error of :func:`_fast_carry_run` (computed once per test process)."""
    t_err, r_err = _fast_carry_run(tracker_seed, **dict(overrides))
    return float(t_err.max()), float(r_err.max())


def test_a_fast_partly_seen_carry_follows_the_hand():
    """With the carry settings (FAST_CARRY) the cube carried fast and partly seen keeps nearer the truth than with
    them all off, where it is re-acquired on a wrong face in the hand (20°+) or falls behind the hand: per seed of
    FAST_SEEDS, the worst frame's translation error off minus on, median over the seeds more than 5 mm (7-12 mm
    on two seeds, -5 on the third), and the same for the rotation error, more than 10° (25-27°, -15°); with the
    settings the median worst frame within 35 mm (11-30 mm)."""
    all_off = {k: (0.0 if k == "carry_keep_visibility" else False) for k in FAST_CARRY}
    on = np.array([_fast_carry_worst(s, tuple(FAST_CARRY.items())) for s in FAST_SEEDS])
    off = np.array([_fast_carry_worst(s, tuple(all_off.items())) for s in FAST_SEEDS])
    assert np.median(on[:, 0]) < 0.035, on
    assert np.median(off[:, 0] - on[:, 0]) > 0.005, (off, on)
    assert np.median(off[:, 1] - on[:, 1]) > 10.0, (off, on)


@pytest.mark.parametrize("setting", ["carry_blob_depth", "carry_keep_visibility", "carry_reacquire_keep_turn",
                                     "carry_rest_prior"])
def test_each_fast_carry_setting_is_needed(setting):
    """Without any one of the four settings the fast carry of :func:`_fast_carry_run` goes wrong: re-seeded on its
    blob at its old depth it falls behind a hand moving toward the camera (carry_blob_depth); dropped by a one-frame
    rise of its visible-fraction estimate it is not moved with the hand (carry_keep_visibility); re-acquired from a
    sliver it lands on a wrong face (carry_reacquire_keep_turn); its coordinate pass walks it off the hand
    (carry_rest_prior)."""
    off = 0.0 if setting == "carry_keep_visibility" else False
    t_err, r_err = _fast_carry_run(**dict(FAST_CARRY, **{setting: off}))
    assert t_err.max() > 0.015 or r_err.max() > 10.0, (t_err.max(), r_err.max())


def _whipped_out_of_view_run(keep_unseen: float, tracker_seed: int = 0) -> np.ndarray:
    """Simulated learning-5 with a swaying camera, speed 2, occlusion 1.5 (tuning seed 0), frames 160-200, tracked as
    ``track`` does (default preset, ``carry_keep_unseen`` = ``keep_unseen``, tracker seed 0) from the true poses at
    frame 160: the hand carries the blue cube, 31 % of it in view at frame 172, then whips it 2 cm in one frame
    (173) out of view and carries it hidden to frame 223. Returns blue's translation error (m) per frame. Run without
    blob_follow_inside_px (off; on for part of session 16): with it the cube's sliver, inside its footprint when the
    hand picks it up at frame 164, is not followed, the carry starts late and stays about 20 mm off. Run without
    carry_keep_moving (on by default since session 17), which keeps the cube in the hand at frame 173 as well: with it
    and without carry_keep_unseen the last ten frames are 5.6 mm off on average. Run without carry_upright_air (on by
    default since session 24; with it and carry_keep_unseen the worst error here is 15.0 mm) and without
    carry_over_sliver, carry_sliver_particles and carry_lift_lookback (on by default since session 29; with them the
    run without carry_keep_unseen is 11.4 mm off over its last ten frames)."""
    from tracker.sources.simulator import SimOptions, SimulatedTable

    src = SimulatedTable("learning-5", seed=0, realtime=False, n_frames=201,
                         options=SimOptions(speed=2.0, occlusion=1.5, camera_motion="sway"))
    cfg = TrackerConfig.preset("default").with_overrides(carry_keep_unseen=keep_unseen, blob_follow_inside_px=0.0,
                                                         carry_keep_moving=0.0, carry_upright_air=False, **SLIVER_OFF)
    return np.array([state.poses["blue"].translation_error(truth["blue"])
                     for _, state, truth in _session_window(src, cfg, range(160, 201), seed=tracker_seed)])


def _session_window(src, cfg, frames, seed: int):
    """``(frame index, tracked state, ground-truth poses)`` of each of ``frames`` of the simulator ``src``, tracked as
    ``track`` tracks a recording (a TrackSession started from the truth at the first of them, tracker ``seed``)."""
    from app.commands.track import TrackSession

    session = None
    for i in frames:
        frame = src.render(i)
        truth = frame.meta["groundtruth"]["poses"]
        if session is None:
            session = TrackSession(src.parts, src.intrinsics, truth, cfg, seed=seed)
        state, _ = session.step(frame)
        yield i, state, truth


WHIP_SEEDS = (0, 1, 2)
"""Tracker seeds of the whipped-out-of-view test (its bounds hold for the medians over them: with carry_keep_unseen
the worst error is 11.4-14.3 mm over these seeds, without it the last ten frames 18.6-129 mm, 11.2 with the
refinement's early end on seed 0; session 30)."""


def test_a_carried_part_whipped_out_of_view_stays_in_the_hand_when_its_place_does_not_show_it():
    """Last frame's estimate (31 % visible) would end the carry; this frame's depth no longer shows the cube where it
    was, so with carry_keep_unseen it stays in the hand and follows it (within 16 mm); without, the hand's 2 cm that
    frame are lost and the hidden carry goes on 2 cm off (4 cm before carry_anchor_start, on by default since
    session 16). Medians over WHIP_SEEDS."""
    on = [_whipped_out_of_view_run(0.3, s).max() for s in WHIP_SEEDS]
    off = [_whipped_out_of_view_run(0.0, s)[-10:].mean() for s in WHIP_SEEDS]
    assert np.median(on) < 0.016, on
    assert np.median(off) > 0.017, off


def test_seen_where_it_was_measures_how_much_of_the_estimate_the_depth_shows():
    """The fraction of the silhouette where the depth meets the estimate's surface: all of it for a cube resting in
    view, next to none once it is estimated 8 cm above where it rests (the depth shows what lies behind)."""
    from tracker.filter.hidden_parts import seen_where_it_was
    from tracker.filter.particle_filter import MultiObjectTracker
    from tracker.geometry.pose import Pose
    from tracker.sources.simulator import SimulatedTable

    src = SimulatedTable("static", seed=1, realtime=False, n_frames=1)
    frame = src.render(0)
    truth = frame.meta["groundtruth"]["poses"]
    trk = MultiObjectTracker(src.parts, src.intrinsics, TrackerConfig.preset("default"), seed=0)
    trk.initialize(truth)
    i = trk.names.index("red")
    assert seen_where_it_was(trk, i, frame.depth) > 0.9
    up = np.asarray(src.table_plane[0], np.float64)  # the table's normal, toward the camera
    trk.initialize({**truth, "red": Pose(t=truth["red"].t + 0.08 * up, q=truth["red"].q)})
    assert seen_where_it_was(trk, i, frame.depth) < 0.1


def _moved_before_its_carry_run(anchor_motion: bool, tracker_seed: int = 3) -> tuple[float, float, np.ndarray]:
    """Simulated guess-1 with a hand-held camera, speed 1.5 (tuning seed 1), frames 170-200, tracked as ``track``
    does (default preset, ``rest_anchor_motion`` = ``anchor_motion``, without carry_anchor_start, which sets the
    anchor when the carry starts and so gives both runs the same rotation in the hand, tracker seed 3) from the true
    poses at frame
    170: the hand picks up the yellow cube and moves it 1-3 cm a frame while 40-60 % of it is seen (the refinement
    places it, no carry yet), then it vanishes in the hand (frame 188) and is carried hidden. Returns the rest
    anchor's translation error (m) and rotation error (deg) at the last frame before 187 that the refinement placed
    it, and yellow's rotation error (deg) over frames 191-200 (hidden in the hand, the rest prior on)."""
    from app.commands.track import TrackSession
    from tracker.filter.scene_motion import placed_by_depth
    from tracker.geometry.symmetry import symmetric_rotation_error, symmetry_group
    from tracker.sources.simulator import SimOptions, SimulatedTable

    src = SimulatedTable("guess-1", seed=1, realtime=False, n_frames=201,
                         options=SimOptions(speed=1.5, occlusion=1.0, camera_motion="handheld"))
    group = symmetry_group(next(p for p in src.parts if p.name == "yellow"))
    cfg = TrackerConfig.preset("default").with_overrides(rest_anchor_motion=anchor_motion, carry_anchor_start=False)
    session, anchor, r_err = None, (np.inf, np.inf), []
    for i in range(170, 201):
        frame = src.render(i)
        truth = frame.meta["groundtruth"]["poses"]
        if session is None:
            session = TrackSession(src.parts, src.intrinsics, truth, cfg, seed=tracker_seed)
        state, _ = session.step(frame)
        trk, j = session.tracker, session.tracker.names.index("yellow")
        if i < 187 and placed_by_depth(trk, j):
            anchor = (float(np.linalg.norm(trk._rest_t[j] - truth["yellow"].t)),
                      float(np.degrees(symmetric_rotation_error(trk._rest_R[j], truth["yellow"].R, group))))
        if i > 190:
            r_err.append(np.degrees(symmetric_rotation_error(state.poses["yellow"].R, truth["yellow"].R, group)))
    return anchor[0], anchor[1], np.array(r_err)


def test_a_part_moved_by_the_hand_before_its_carry_takes_its_placed_pose_as_rest_anchor():
    """rest_anchor_motion: the cube the hand moves while partly seen has its rest anchor at its refined pose (within
    5 mm) when it vanishes in the hand, so once hidden the rest prior holds the rotation it was last seen with; without
    it the anchor stays where the cube was last fully seen, several centimetres and degrees behind, and the hidden
    cube is turned back to that rotation (its rotation error in the hand larger)."""
    t_on, rdeg_on, r_on = _moved_before_its_carry_run(True)
    t_off, rdeg_off, r_off = _moved_before_its_carry_run(False)
    assert t_on < 0.005 and rdeg_on < 4.0, (t_on, rdeg_on)
    assert t_off > 0.03 and rdeg_off > 8.0, (t_off, rdeg_off)
    assert r_on.mean() < r_off.mean() - 3.0, (r_on.mean(), r_off.mean())



def _carry_start_run(tracker_seed: int = 3, **overrides) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_carry_start_run_once`, computed once per test process for each seed and set of settings."""
    return _carry_start_cached(tracker_seed, _changed(overrides))


@cache
def _carry_start_cached(tracker_seed: int, overrides: tuple) -> tuple:
    return _read_only(_carry_start_run_once(tracker_seed, **dict(overrides)))


def _carry_start_run_once(tracker_seed: int = 3, **overrides) -> tuple[np.ndarray, np.ndarray]:
    """Simulated guess-1 with a hand-held camera, speed 1.5 (tuning seed 1), frames 170-200, tracked as ``track`` does
    (default preset with ``overrides``, tracker seed 3) from the true poses at frame 170: the hand moves the yellow
    cube 2-3 cm a frame while part of it is seen (its rest anchor stays where it was last fully seen), then carries
    it, 14 % and 6 % of it in view in frames 188-189 (the colour stage re-seeds it on that sliver), hidden from frame
    190. Returns yellow's translation error (m) over frames 188-200 and its rotation error (deg, cube symmetry) over
    frames 191-200 (hidden in the hand, the rest prior on)."""
    from tracker.geometry.symmetry import symmetric_rotation_error, symmetry_group
    from tracker.sources.simulator import SimOptions, SimulatedTable

    src = SimulatedTable("guess-1", seed=1, realtime=False, n_frames=201,
                         options=SimOptions(speed=1.5, occlusion=1.0, camera_motion="handheld"))
    group = symmetry_group(next(p for p in src.parts if p.name == "yellow"))
    cfg = TrackerConfig.preset("default").with_overrides(**overrides)
    t_err, r_err = [], []
    for i, state, truth in _session_window(src, cfg, range(170, 201), seed=tracker_seed):
        if i >= 188:
            t_err.append(state.poses["yellow"].translation_error(truth["yellow"]))
        if i > 190:
            assert "yellow" in state.carried  # the run really carries it hidden
            r_err.append(np.degrees(symmetric_rotation_error(state.poses["yellow"].R, truth["yellow"].R, group)))
    return np.array(t_err), np.array(r_err)


def test_a_carried_cube_keeps_the_rotation_it_vanished_with():
    """carry_anchor_start: the rest anchor is set to the estimate when the carry starts, so the hidden carried cube's
    rotation is not snapped to the stale anchor from where it was last fully seen (6-10 degrees off with it, 22-25
    without)."""
    (_, on), (_, off) = _carry_start_run(carry_anchor_start=True), _carry_start_run(carry_anchor_start=False)
    assert on.max() < 12.0, on  # 2.0-6.6 over tracker seeds 3-5 and the refinement's early end (session 30)
    assert off.mean() > on.mean() + 4.0, (off.mean(), on.mean())  # 5.8-15.1 there


SLIVER_SEEDS = (3, 4, 5)
"""Tracker seeds of the sliver test (medians over them: with seed 4 the setting's cube is 32 mm off, 13 without)."""


def test_a_carried_cube_moves_with_the_hand_not_onto_its_sliver():
    """carry_over_sliver: the cube carried 3 cm a frame with only a sliver in view is moved by the hand from where it
    was, not left where the colour stage re-seeded it on its sliver's centroid (2-5 mm off while the hand moves it,
    2 cm without; medians over SLIVER_SEEDS)."""
    on = np.array([_carry_start_run(s, carry_over_sliver=True)[0][:7].mean() for s in SLIVER_SEEDS])
    off = np.array([_carry_start_run(s, carry_over_sliver=False)[0][:7].mean() for s in SLIVER_SEEDS])
    assert np.median(on) < 0.012, on  # frames 188-194, while the hand moves it
    assert np.median(off - on) > 0.006, (off, on)


def _sliver_reseed_then_carry(particles: bool) -> tuple[float, float]:
    """A static scene (seed 1) set at the truth; red is re-seeded as the colour stage re-seeds a carried part on a
    sliver's centroid 3 cm to its side (30 % of its particles re-drawn there with 8 mm spread, its estimate moved there,
    its estimate and particles from before kept for the hand carry), then this frame's hand motion (1 cm along x, no
    turn) is applied by ``carry_over_sliver`` with ``carry_sliver_particles`` = ``particles``. Returns the distances (m)
    of red's estimate and of its particles' mean from where the hand's motion takes its pre-re-seed position."""
    from tracker.filter.hand_carry import carry_over_sliver
    from tracker.filter.particle_filter import MultiObjectTracker
    from tracker.geometry.pose import Pose
    from tracker.sources.simulator import SimulatedTable

    src = SimulatedTable("static", seed=1, realtime=False, n_frames=1)
    truth = src.render(0).meta["groundtruth"]["poses"]
    cfg = TrackerConfig.preset("default").with_overrides(carry_over_sliver=True, carry_sliver_particles=particles)
    trk = MultiObjectTracker(src.parts, src.intrinsics, cfg, seed=0)
    trk.initialize(truth)
    i = trk.names.index("red")
    trk.p[:, i] += trk.rng.normal(0.0, 0.004, trk.p[:, i].shape)  # a filter's spread about the estimate
    pre = trk.estimates["red"]
    trk._pre_reseed, trk._pre_reseed_p = {i: pre}, {i: trk.p[:, i].copy()}
    n = trk.p.shape[0]
    sel = trk.rng.choice(n, int(0.3 * n), replace=False)
    target = pre.t + np.array([0.03, 0.0, 0.0])
    trk.p[sel, i] = target + trk.rng.normal(0.0, 0.008, (sel.size, 3))
    trk.estimates["red"] = Pose.from_rt(pre.R, target)
    rot, step = np.eye(3), np.array([0.01, 0.0, 0.0])
    centre = rot @ (pre.R @ trk.center[i] + pre.t) + step
    assert carry_over_sliver(trk, i, rot, step, trk.intrinsics.project(centre[None])[0])
    goal = rot @ pre.t + step
    return float(np.linalg.norm(trk.estimates["red"].t - goal)), float(np.linalg.norm(trk.p[:, i].mean(0) - goal))


def test_a_part_carried_over_its_sliver_takes_its_particles_with_it():
    """carry_sliver_particles: the re-seed on the sliver is undone and the hand's motion moves the particles from where
    they were, so their mean is where the estimate is (within 4 mm); without it (set off) the 70 % of the particles not
    re-drawn are moved by the estimate's jump back from the sliver and their mean lies 2 cm from it (the coordinate
    passes then pulled a carried cube 3 to 12 mm off on a tuning trace)."""
    (est_on, mean_on), (est_off, mean_off) = _sliver_reseed_then_carry(True), _sliver_reseed_then_carry(False)
    assert est_on < 1e-6 and est_off < 1e-6, (est_on, est_off)  # the estimate goes where the hand takes it either way
    assert mean_on < 0.004, mean_on
    assert mean_off > 0.015, mean_off

def _visibility_crossing_run(carry_keep_moving: float, tracker_seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Simulated learning-5, fixed camera (tuning seed 2, occlusion 1, speed 2), frames 120-160, tracked from the
    truth at frame 120, tracker seed 0: a hand carries the green cube 35-39 % visible; at frame 147 its estimated
    visible fraction reaches 0.30 while the hand moves it 1 cm, then the hand hides it and carries it on. Returns
    whether green is carried and its symmetry-aware rotation error (deg), per frame from 140. Run without
    carry_upright_air (on by default since session 24; with it the cube stays in the hand at frame 147 with or without
    carry_keep_moving, the two runs are identical and the hidden carry is 5-6 degrees off) and without
    reacquire_tilt_gain (on by default since session 26; with it the re-check at the release no longer fits the
    sliver tilted: 8.0 degrees with carry_keep_moving at frame 147, 7.5 without)."""
    from tracker.geometry.symmetry import symmetric_rotation_error, symmetry_group
    from tracker.sources.simulator import SimOptions, SimulatedTable

    src = SimulatedTable("learning-5", seed=2, realtime=False, n_frames=161,
                         options=SimOptions(speed=2.0, occlusion=1.0, camera_motion="none"))
    group = symmetry_group(next(p for p in src.parts if p.name == "green"))
    cfg = TrackerConfig.preset("default").with_overrides(carry_keep_moving=carry_keep_moving, carry_upright_air=False,
                                                         reacquire_tilt_gain=0.0)
    carried, r_err = [], []
    for i, state, truth in _session_window(src, cfg, range(120, 161), seed=tracker_seed):
        if i >= 140:
            carried.append("green" in state.carried)
            r_err.append(np.degrees(symmetric_rotation_error(state.poses["green"].R, truth["green"].R, group)))
    return np.array(carried), np.array(r_err)


VISIBILITY_SEEDS = (0, 1, 2)
"""Tracker seeds of the visibility-crossing test. The crossing itself depends on the estimate's visible fraction:
it happens with tracker seed 0, not with 1 or 2 nor with the refinement's early end on seed 0 (session 30), where
both arms run the same. The test asks for it in at least one seed and checks every seed where it happens."""


def test_a_carried_cube_whose_visible_fraction_crosses_the_bound_stays_in_the_moving_hand():
    """carry_keep_moving: at frame 147 (tracker seed 0) the carry would end (visible fraction 0.30) while the hand
    moves the cube 1 cm; the depth shows it where the hand takes it, not where it was, so it stays in the hand (about 8
    degrees off, 10-12 for the rest of the hidden carry). Without, the carry is dropped for that frame, the re-check
    at the release fits its sliver 21 degrees off and the hidden carry keeps that (23-28 degrees). Checked on every
    seed of VISIBILITY_SEEDS where the arms differ (the crossing happened), at its first frame carried with the
    setting only; at least one seed must show it."""
    shown = 0
    for seed in VISIBILITY_SEEDS:
        (on_c, on_r), (off_c, off_r) = _visibility_crossing_run(0.005, seed), _visibility_crossing_run(0.0, seed)
        if np.array_equal(on_c, off_c) and np.array_equal(on_r, off_r):
            continue  # no crossing with this seed: the setting did not act
        shown += 1
        k = int(np.flatnonzero(on_c & ~off_c)[0])  # the crossing: carried with the setting, dropped without
        assert on_r[k] < 12.0 and off_r[k] > 18.0, (seed, k, on_r[k], off_r[k])
        late = slice(k + 5, None)
        assert off_r[late].mean() > on_r[late].mean() + 10.0, (seed, off_r[late].mean(), on_r[late].mean())
    assert shown >= 1



def _tilted_carry_run(upright_air: bool, tracker_seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Simulated guess-3 with a swaying camera, speed 1, occlusion 1 (tuning seed 2), frames 95-155, tracked as
    ``track`` does (default preset, ``carry_upright_air`` = ``upright_air``, tracker seed 0) from the true poses at
    frame 95: the hand lifts the red cube and carries it about 50 frames completely hidden in the air. Returns red's
    rotation error (deg, cube symmetry) and whether the tracker carries it, per frame."""
    from tracker.geometry.symmetry import symmetric_rotation_error, symmetry_group
    from tracker.sources.simulator import SimOptions, SimulatedTable

    src = SimulatedTable("guess-3", seed=2, realtime=False, n_frames=156,
                         options=SimOptions(speed=1.0, occlusion=1.0, camera_motion="sway"))
    cfg = TrackerConfig.preset("default").with_overrides(carry_upright_air=upright_air)
    group = symmetry_group(next(p for p in src.parts if p.name == "red"))
    r_err, carried = [], []
    for _, state, truth in _session_window(src, cfg, range(95, 156), seed=tracker_seed):
        r_err.append(np.degrees(symmetric_rotation_error(state.poses["red"].R, truth["red"].R, group)))
        carried.append("red" in state.carried)
    return np.array(r_err), np.array(carried)


def test_a_part_carried_hidden_in_the_air_keeps_upright():
    """carry_upright_air: the red cube carried hidden in the air (:func:`_tilted_carry_run`) is turned upright after
    each frame's hand motion, so the tilt the hand registration picks up over the long hidden carry does not add
    up (worst rotation error while carried 3.3 degrees); without it (set off explicitly) it grows past the 5 degree
    bound (9.5 degrees, mostly tilt)."""
    on, carried_on = _tilted_carry_run(True)
    off, carried_off = _tilted_carry_run(False)
    assert carried_on.sum() > 30 and carried_off.sum() > 30
    assert on[carried_on].max() < 6.0, on[carried_on].max()
    assert off[carried_off].max() > 7.0, off[carried_off].max()


def _fast_start_run(placed_step: bool | None, across: bool = True) -> np.ndarray:
    """Distance (mm) of a part from the truth over five frames: four noise-free fingers over a table (the fingers of
    ``tests/test_projective_icp.py``) move 2.2 cm a frame across themselves (``across``) or 1.5 cm along; the part
    under them is seen and placed by the refinement in frames 0-1, re-seeded on its blob every frame (its remembered
    positions forgotten, as the colour stage does), hidden from frame 2: the carry starts by registering frame 1's
    hand points to frame 2's."""
    from tests.test_projective_icp import INTR, _fingers

    plane = (np.array([0.0, 0.0, -1.0]), 0.55)  # a table 0.55 m away, under the fingers at 0.45 m
    cfg = CFG if placed_step is None else CFG.with_overrides(carry_start_placed_step=placed_step)
    carry = HandCarry(1, cfg, INTR, np.array([0.02]))
    heights = np.array([0.05])
    pos, errs = np.array([[0.0, 0.0, 0.47]]), []
    for k in range(5):
        shift = np.array([0.0, 0.022 * k, 0.0]) if across else np.array([0.015 * k, 0.0, 0.0])
        truth = np.array([[0.0, 0.0, 0.47]]) + shift
        depth = _fingers(shift)
        depth = np.where(np.isfinite(depth), depth, np.float32(0.55))
        hidden = np.array([k >= 2])
        if k < 2:
            pos = truth.copy()  # seen: placed where it is
        rot, d = carry.update(depth, pos, hidden, ~hidden, heights, plane)
        pos = np.einsum("kij,kj->ki", rot, pos) + d
        if k < 2:
            carry.note_placed(np.array([True]), np.eye(3)[None], pos)
        carry.record(0.1 * k, pos)
        carry.forget(0)
        errs.append(1e3 * float(np.linalg.norm(pos - truth)))
    assert carry.carried.tolist() == [True]
    return np.array(errs)


def test_a_fast_carry_starts_from_the_placed_step_when_re_seeds_wiped_the_remembered_one():
    """carry_start_placed_step: the hand steps beyond the registration's 2 cm pairing bound at the carry's start and
    the part's remembered step is gone (re-seeded): from no motion the first registration snaps to the neighbouring
    finger (15.6 mm off; 5.3 mm along), from the step between the two placements it follows the hand (1.5 mm; 0.2
    mm), and keeps it over the next frames (the next registration starts from this one's step). Off is the
    default."""
    off, on = _fast_start_run(False), _fast_start_run(True)
    assert off[2] > 10.0 and off[4] > 10.0, off
    assert on[2] < 3.0 and on[4] < 5.0, on
    along_off, along_on = _fast_start_run(False, across=False), _fast_start_run(True, across=False)
    assert along_off[2] > 3.0 and along_on[2] < 1.5, (along_off, along_on)
    assert np.array_equal(_fast_start_run(None), off)


def _partly_seen_start_run(**overrides) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Simulated guess-3, hand-held camera, occlusion 1.5, speed 2 (tuning seed 2), frames 60-76, tracked as ``track``
    does from the truth at frame 60 (tracker seed 0), default preset with carry_start_placed_step and ``overrides``:
    the hand slides the red cube 2-3 cm a frame while it is still partly seen (re-seeded on its blob, so its particles
    spread over ~25 mm), takes it at frame 69 (~30 % of it still seen under the hand) and carries it hidden. Returns
    red's translation error (mm), whether it is carried, and whether its coordinate pass was skipped, per frame."""
    from app.commands.track import TrackSession
    from tracker.sources.simulator import SimOptions, SimulatedTable

    src = SimulatedTable("guess-3", seed=2, realtime=False, n_frames=77,
                         options=SimOptions(speed=2.0, occlusion=1.5, camera_motion="handheld"))
    cfg = TrackerConfig.preset("default").with_overrides(carry_start_placed_step=True, **overrides)
    session, errs, carried, skipped = None, [], [], []
    for i in range(60, 77):
        frame = src.render(i)
        truth = frame.meta["groundtruth"]["poses"]
        if session is None:
            session = TrackSession(src.parts, src.intrinsics, truth, cfg, seed=0)
        state, _ = session.step(frame)
        errs.append(1e3 * state.poses["red"].translation_error(truth["red"]))
        carried.append("red" in state.carried)
        skipped.append(bool(session.tracker._quiet_now[session.tracker.names.index("red")]))
    return np.array(errs), np.array(carried), np.array(skipped)


def test_a_carry_started_on_a_partly_seen_part_is_not_pulled_off_by_its_spread_particles():
    """carry_start_collapse: at frame 69 the carry starts right (the placed step), but red's particles are spread over
    ~25 mm by the re-seeds on its blob; the likelihood on its few visible pixels picks among them and pulls the
    estimate 12.5 mm off, and the hidden carry keeps 17-19 mm to frame 76. With the particles collapsed onto the
    carried pose at the carry's start: 3.9 mm, 7.5-10 mm after. carry_start_skip (with it) skips red's pass in that
    frame only: 2.3 mm, 6.7-8.5 mm after. Both off is the default bit for bit."""
    off, off_carried, off_skipped = _partly_seen_start_run()
    start = 69 - 60
    assert off_carried[start] and not off_carried[:start].any()  # the carry starts at frame 69 in every arm
    assert off[start] > 10.0 and off[start + 1 :].mean() > 15.0, off
    on, on_carried, _ = _partly_seen_start_run(carry_start_collapse=True)
    assert on_carried[start] and on[start] < 6.0 and on[start + 1 :].mean() < 12.0, on
    both, _, both_skipped = _partly_seen_start_run(carry_start_collapse=True, carry_start_skip=True)
    assert both[start] < 4.0 and both[start + 1 :].mean() < 12.0, both
    assert not off_skipped.any() and both_skipped[start] and not both_skipped[start + 1 :].any(), both_skipped
    default, _, _ = _partly_seen_start_run(carry_start_collapse=False, carry_start_skip=False)
    assert np.array_equal(default, off)


def test_shifted_starts_find_a_hand_step_beyond_the_pairing_bound():
    """carry_shift_starts: noise-free fingers (``tests/test_projective_icp.py``) moved 3.2 cm across themselves and
    toward or away from the camera, registered from no motion (a carry's step with no guess): the pairs within the
    2 cm bound lead the ICP into a wrong minimum (18.8-19.0 mm off, turned 0.13-0.14 rad); a start shifted 2 cm along
    y lies within the bound of the true step and its residual wins (0.3 mm). Off (0) is the call without it, bit for
    bit."""
    from tests.test_projective_icp import _fingers, _thinned

    part = np.array([0.0, 0.0, 0.47])
    src = _thinned(_fingers(np.zeros(3)), part, 0.08)
    for true in (np.array([0.0, 0.03, 0.01]), np.array([0.0, 0.025, -0.02])):
        dst = _thinned(_fingers(true), part, 0.13)
        w_off, t_off = register_rigid(src, dst, 8, 0.05, 0.2, None, None, True)
        w_on, t_on = register_rigid(src, dst, 8, 0.05, 0.2, None, None, True, None, 0.02)
        assert np.linalg.norm(t_off - true) > 0.015, t_off
        assert np.linalg.norm(t_on - true) < 0.001 and np.linalg.norm(w_on) < 0.01, (t_on, w_on)
        w0, t0 = register_rigid(src, dst, 8, 0.05, 0.2, None, None, True, None, 0.0)
        assert np.array_equal(w0, w_off) and np.array_equal(t0, t_off)


@cache
def _fast_hand_run(shift: float) -> tuple[np.ndarray, np.ndarray]:
    """Simulated guess-3, hand-held camera, occlusion 1.5, speed 2 (tuning seed 2), frames 60-79, tracked as ``track``
    does from the truth at frame 60 (tracker seed 1, default preset, ``carry_shift_starts`` = ``shift``): the hand
    slides the red cube 3-4 cm a frame and takes it at frame 70. Returns red's translation error (mm) and whether it
    is carried, per frame."""
    from tracker.sources.simulator import SimOptions, SimulatedTable

    src = SimulatedTable("guess-3", seed=2, realtime=False, n_frames=80,
                         options=SimOptions(speed=2.0, occlusion=1.5, camera_motion="handheld"))
    cfg = TrackerConfig.preset("default").with_overrides(carry_shift_starts=shift)
    errs, carried = [], []
    for _, state, truth in _session_window(src, cfg, range(60, 80), seed=1):
        errs.append(1e3 * state.poses["red"].translation_error(truth["red"]))
        carried.append("red" in state.carried)
    return np.array(errs), np.array(carried)


def test_a_carry_whose_hand_steps_beyond_the_pairing_bound_follows_it_from_shifted_starts():
    """carry_shift_starts: the carry's first registration (frame 69's hand points to frame 70's) starts from no motion
    and from red's remembered step (wiped by the re-seeds on its blob), the hand's 3.7 cm step lies beyond the 2 cm
    pairing bound, the ICP settles 2-3 cm off and the carry keeps that (32-35 mm to frame 79). With starts shifted
    2 cm along each axis one lands within the bound and its residual wins: 4-6 mm. The frames before the carry are the
    same (the setting acts only in a registration); off is the default."""
    off, off_carried = _fast_hand_run(0.0)
    on, on_carried = _fast_hand_run(0.02)
    start = 70 - 60
    assert off_carried[start:].all() and on_carried[start:].all() and not off_carried[:start].any()
    assert np.array_equal(off[:start], on[:start])
    assert off[start:].mean() > 25.0, off
    assert on[start:].max() < 8.0, on
    assert TrackerConfig.preset("default").carry_shift_starts == 0.0  # off is the default


def test_the_keep_moving_test_moves_a_re_seeded_part_from_its_pose_before_the_re_seed():
    """carry_keep_moving_pre_reseed: simulated guess-3, hand-held camera, occlusion 1.5, speed 2 (tuning seed 2),
    frame 70: the hand carries the red cube 3.7 cm a frame, ~25 % of it seen, and the colour stage has re-seeded it on
    its blob (20 mm off the truth, as on the tuning trace of tracker seed 1 with carry_start_placed_step). The
    keep-moving test (its visible fraction would end the carry) moved the re-seeded estimate by the hand's step (53 mm
    off; the depth shows 3 % of it there, 5 % where it was): dropped. From its pose before the re-seed, where the
    hand's registration started, the step takes it to the truth (10 % shown): kept in the hand. Off is the
    default."""
    from app.commands.track import TrackSession
    from tracker.filter.hidden_parts import moved_with_hand
    from tracker.geometry.pose import Pose
    from tracker.sources.simulator import SimOptions, SimulatedTable

    src = SimulatedTable("guess-3", seed=2, realtime=False, n_frames=71,
                         options=SimOptions(speed=2.0, occlusion=1.5, camera_motion="handheld"))
    g69, g70 = src.render(69).meta["groundtruth"], src.render(70).meta["groundtruth"]
    depth = src.render(70).depth
    M = np.linalg.inv(g70["camera_pose"].as_matrix()) @ g69["camera_pose"].as_matrix()
    before = Pose.from_matrix(M @ g69["poses"]["red"].as_matrix())  # last frame's pose, in this frame's camera
    Q = g70["poses"]["red"].as_matrix() @ np.linalg.inv(before.as_matrix())  # the hand's true motion this frame
    reseeded = Pose.from_rt(before.R, before.t + np.array([-0.049, -0.002, 0.020]))
    kept = {}
    for on in (False, True):
        cfg = TrackerConfig.preset("default").with_overrides(carry_keep_moving_pre_reseed=on)
        trk = TrackSession(src.parts, src.intrinsics, g70["poses"], cfg, seed=0).tracker
        red = trk.names.index("red")
        trk.estimates["red"] = reseeded
        trk._pre_reseed = {red: before}
        kept[on] = moved_with_hand(trk, red, depth, Q[:3, :3], Q[:3, 3])
    assert kept == {False: False, True: True}, kept
    assert not TrackerConfig.preset("default").carry_keep_moving_pre_reseed
