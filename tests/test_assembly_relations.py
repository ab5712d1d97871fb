"""Relations, connection score, cube symmetry (the four cases), N_checks and breaking."""

import numpy as np
import pytest

from tracker.assembly.connection_monitor import AssemblyParams, ConnectionMonitor, ConnectionSpec
from tracker.assembly.connection_score import allocate_particles, connection_score, score_distance
from tracker.assembly.cube_symmetry import SymmetryState, case1_first_rotations
from tracker.assembly.relations import (
    m_q_from_angle,
    position_within,
    relative_pose,
    relative_position_table,
    rotation_within,
    table_rotation,
    table_rotation_from_normal,
    table_to_camera_from_plane,
)
from tracker.assembly.synthetic import default_table_to_camera
from tracker.geometry.parts import CUBE_EDGE, PartSpec
from tracker.geometry.pose import Pose
from tracker.geometry.symmetry import cube_group

A = CUBE_EDGE


def rz(deg):
    return Pose.from_rotvec(np.array([0, 0, np.radians(deg)]), np.zeros(3)).R


def test_relative_pose_hand_computed():
    pa = Pose.from_rt(rz(90), np.array([0.0, 0.0, 1.0]))
    pb = Pose.from_rt(np.eye(3), np.array([0.0, A, 1.0]))
    p_ab, R_ab = relative_pose(pa, pb)
    # R_aᵀ (0, a, 0) with R_a = 90° about z: (a, 0, 0); relative rotation −90° about z.
    np.testing.assert_allclose(p_ab, [A, 0, 0], atol=1e-12)
    np.testing.assert_allclose(R_ab, rz(-90), atol=1e-12)


def test_table_relative_position_eq_5_8_corrected():
    R_ot = table_rotation_from_normal(np.array([0.0, -1.0, 0.0]))  # level camera: up = −y_camera
    np.testing.assert_allclose(R_ot, [[1, 0, 0], [0, -1, 0], [0, 0, -1]], atol=1e-12)
    d = relative_position_table(np.array([0, 0, 1.0]), np.array([0.1, -0.05, 1.0]), R_ot)
    np.testing.assert_allclose(d, [0.1, 0.05, 0.0], atol=1e-12)  # y component = N·Δp (up is positive)
    T = table_to_camera_from_plane(np.array([0.0, -0.6, -0.8]), 0.4)
    np.testing.assert_allclose(table_rotation(T)[1], [0.0, -0.6, -0.8], atol=1e-12)
    np.testing.assert_allclose(T.t, [0, 0, 0.5], atol=1e-12)  # optical axis meets the plane at z = 0.4 / 0.8


def test_equality_tests():
    assert position_within([A, 0, 0], [A + 0.009, -0.009, 0.009], 0.01)
    assert not position_within([A, 0, 0], [A + 0.011, 0, 0], 0.01)
    assert not position_within([A, 0, 0], [A, 0, 0.011], (0.02, 0.02, 0.01))
    m_q = m_q_from_angle(np.radians(20))
    assert m_q == pytest.approx(1 - np.cos(np.radians(10)))
    assert rotation_within(np.eye(3), rz(19), m_q)
    assert not rotation_within(np.eye(3), rz(21), m_q)


def test_connection_score_and_allocation():
    p = np.array([A, 0, 0])
    assert connection_score(p, np.eye(3), p, np.eye(3), 0.01, 3) == pytest.approx(1.0)
    # inside the margins on every axis: still 1 (sum of squares ≤ 3)
    assert connection_score(p, np.eye(3), p + 0.009, np.eye(3), 0.01, 3) == pytest.approx(1.0)
    far = p + np.array([0.05, 0, 0])
    e2 = 25.0
    assert score_distance(p, far, 0.01, 3) == pytest.approx(np.sqrt(3 * (e2 - 3) + 1))
    s3 = connection_score(p, np.eye(3), far, np.eye(3), 0.01, 3)
    s7 = connection_score(p, np.eye(3), far, np.eye(3), 0.01, 7)
    assert s3 == pytest.approx(1 / np.sqrt(67)) and s7 < s3  # larger K drops faster
    assert allocate_particles(1.0, 9) == 9 and allocate_particles(0.5, 9) == 5 and allocate_particles(0.05, 9) == 0


def _check(state, a, b, pa, pb, p_des):
    p_ab, R_ab = relative_pose(pa, pb)
    p_des = np.asarray(p_des, float)
    return state.resolve(a, b, p_ab, R_ab, pa.R, p_des, np.eye(3), np.array([0, -1.0, 0]),
                         lambda p, R: float(np.sum((p - p_des) ** 2)))


G = cube_group()
UP = np.array([0, -1.0, 0])  # table normal in a level camera's frame
R_FUND = np.diag([1.0, -1.0, -1.0])  # fundamental orientation: body y = table up = camera −y


def test_symmetry_case1_any_cubic_rotation_and_vertical_axis_fixed():
    rng = np.random.default_rng(0)
    for _ in range(10):
        Sa, Sb = G[rng.integers(24)], G[rng.integers(24)]
        pa = Pose.from_rt(R_FUND @ Sa, [0, 0, 0.6])
        pb = Pose.from_rt(R_FUND @ Sb, [A, 0, 0.6])  # b to the right of a on the table
        st = SymmetryState({"a": True, "b": True})
        res = _check(st, "a", "b", pa, pb, [A, 0, 0])
        assert res.case == 1
        np.testing.assert_allclose(res.best.p, [A, 0, 0], atol=1e-9)
        np.testing.assert_allclose(res.best.R, np.eye(3), atol=1e-9)
        # the corrected y axis of a points up
        np.testing.assert_allclose(pa.R @ res.best.Q_a.T @ [0, 1, 0], UP, atol=1e-9)
        # a side neighbour never satisfies an "on top" connection
        res_v = _check(st, "a", "b", pa, pb, [0, A, 0])
        assert np.linalg.norm(res_v.best.p - [0, A, 0]) > A
    # vertical first connection: four headings tie and are all kept
    pa = Pose.from_rt(R_FUND, [0, 0, 0.6])
    pb = Pose.from_rt(R_FUND, [0, -A, 0.6])
    assert len(case1_first_rotations(*relative_pose(pa, pb)[:1], np.array([0, A, 0]), pa.R, UP)) == 4


def test_symmetry_cases_2_3_4_use_stored_priors():
    rng = np.random.default_rng(1)
    S = [G[rng.integers(24)] for _ in range(3)]
    pa = Pose.from_rt(R_FUND @ S[0], [0, 0, 0.6])
    pb = Pose.from_rt(R_FUND @ S[1], [A, 0, 0.6])
    pc = Pose.from_rt(R_FUND @ S[2], [2 * A, 0, 0.6])
    st = SymmetryState({"a": True, "b": True, "c": True})
    res = _check(st, "a", "b", pa, pb, [A, 0, 0])
    st.establish("a", "b", res, lambda o: True)
    np.testing.assert_allclose(st.prior_rotation("a", pa.R), res.best.Q_a.T)
    np.testing.assert_allclose(st.fundamental("a"), pa.R @ res.best.Q_a.T)
    # case 2: a (first) has a prior; c is free (checked as "a→c" two edges away)
    r2 = _check(st, "a", "c", pa, pc, [2 * A, 0, 0])
    assert r2.case == 2
    np.testing.assert_allclose(r2.best.Q_a, res.best.Q_a)
    np.testing.assert_allclose(r2.best.p, [2 * A, 0, 0], atol=1e-9)
    # with a's stored prior, c placed on the far side in a's fundamental frame fails
    pc_left = Pose.from_rt(R_FUND @ S[2], [-A, 0, 0.6])
    assert np.linalg.norm(_check(st, "a", "c", pa, pc_left, [2 * A, 0, 0]).best.p - [2 * A, 0, 0]) > A
    # case 3: the second part (b) has a prior, the first (c) is free: c is at +x of b, so b is at −x of c
    r3 = _check(st, "c", "b", pc, pb, [-A, 0, 0])
    assert r3.case == 3
    np.testing.assert_allclose(r3.best.Q_b, res.best.Q_b)
    np.testing.assert_allclose(r3.best.p, [-A, 0, 0], atol=1e-9)
    # case 4: both have priors
    st.establish("b", "c", _check(st, "b", "c", pb, pc, [A, 0, 0]), lambda o: True)
    r4 = _check(st, "a", "c", pa, pc, [2 * A, 0, 0])
    assert r4.case == 4
    np.testing.assert_allclose(r4.best.p, [2 * A, 0, 0], atol=1e-9)
    # breaking b–c drops c's prior
    st.rebuild([("a", "b")])
    assert st.has_prior("a") and not st.has_prior("c")


def _monitor(n_checks=3, n_break=2):
    parts = [PartSpec.cube("a", "red"), PartSpec.cube("b", "green")]
    spec = ConnectionSpec("a", "b", np.array([A, 0, 0]), np.eye(3))
    prm = AssemblyParams(m_p=0.01, N_checks=n_checks, N_break=n_break)
    return ConnectionMonitor(parts, [spec], prm)


def test_n_checks_consecutive_frames_and_breaking_hysteresis():
    T = default_table_to_camera()
    base = T @ Pose(np.array([0, A / 2, 0]))
    near = {"a": base, "b": base @ Pose(np.array([A + 0.003, 0, 0]))}
    off = {"a": base, "b": base @ Pose(np.array([A + 0.03, 0, 0]))}
    slightly_off = {"a": base, "b": base @ Pose(np.array([A + 0.012, 0, 0]))}  # > m_p, < 1.5 m_p
    m = _monitor(n_checks=3, n_break=2)
    seq = [near, near, off, near, near]
    for i, poses in enumerate(seq):
        m.update(i * 0.1, poses, T)
        assert m.status[0].state != "connected"  # never 3 consecutive
    m.update(0.5, near, T)
    assert m.status[0].state == "connected" and m.events[-1].t == pytest.approx(0.5)
    assert m.status[0].state == "connected"
    m.update(0.6, slightly_off, T)
    m.update(0.7, slightly_off, T)
    assert m.status[0].state == "connected"  # within the relaxed break margin
    m.update(0.8, off, T)
    assert m.status[0].state == "connected"  # one failing frame < N_break
    m.update(0.9, off, T)
    assert m.status[0].state == "open" and m.events[-1].type == "disconnected"
    hints = m.connection_hints()
    assert all(not h.locked for h in hints)


def test_hand_gate_holds_a_connection_back_until_the_hand_lets_go():
    """Spec hand-tracking §14.7: pending while a hand touches a part, confirmed n_release free frames later, dropped
    when the test fails meanwhile; gate off (or no hand tracking) = the seed's timing."""
    T = default_table_to_camera()
    base = T @ Pose(np.array([0, A / 2, 0]))
    near = {"a": base, "b": base @ Pose(np.array([A + 0.003, 0, 0]))}
    off = {"a": base, "b": base @ Pose(np.array([A + 0.03, 0, 0]))}
    m = _monitor(n_checks=2)
    m.touched = {"b"}
    for i in range(6):
        m.update(i * 0.1, near, T)
    assert m.status[0].state == "near" and m.status[0].pending and not m.events
    m.touched = set()  # released: n_release = 3 free frames confirm it
    for i in range(6, 8):
        m.update(i * 0.1, near, T)
    assert not m.events and m.status[0].to_dict()["pending"]
    m.update(0.8, near, T)
    assert m.status[0].state == "connected" and m.events[-1].t == pytest.approx(0.8)

    m = _monitor(n_checks=2)
    m.touched = {"a"}
    m.update(0.0, near, T)
    m.update(0.1, near, T)
    m.update(0.2, off, T)  # the test fails while pending: the candidate is dropped
    assert not m.status[0].pending
    m.touched = set()
    m.update(0.3, near, T)
    assert m.status[0].state != "connected"  # the N_checks count restarted
    m.update(0.4, near, T)
    assert m.status[0].state == "connected"

    for gate_off in (AssemblyParams(N_checks=2, hand_gate=False), None):
        m = _monitor(n_checks=2)
        if gate_off is not None:
            m.params = gate_off
        m.touched = {"b"} if gate_off is not None else None
        m.update(0.0, near, T)
        m.update(0.1, near, T)
        assert m.status[0].state == "connected"
    assert AssemblyParams.from_dict({"hand_gate": 0.0}).hand_gate is False
    with pytest.raises(ValueError):
        AssemblyParams.from_dict({"n_release": 0})


def test_hint_relative_pose_in_tracker_frames():
    T = default_table_to_camera()
    rng = np.random.default_rng(3)
    m = _monitor(n_checks=1)
    base = T @ Pose(np.array([0, A / 2, 0]))
    Sa, Sb = G[rng.integers(24)], G[rng.integers(24)]
    pa = Pose.from_rt(base.R @ Sa, base.t)
    pb_fund = base @ Pose(np.array([A, 0, 0]))
    pb = Pose.from_rt(pb_fund.R @ Sb, pb_fund.t)
    m.update(0.0, {"a": pa, "b": pb}, T)
    (h,) = m.connection_hints()
    assert h.locked and h.n_particles == m.params.N_max
    # the hint's relative pose is b's actual pose in a's actual (tracker) frame
    p_ab, R_ab = relative_pose(pa, pb)
    np.testing.assert_allclose(h.relative.t, p_ab, atol=1e-9)
    np.testing.assert_allclose(h.relative.R, R_ab, atol=1e-9)


def test_unexpected_connection_reported():
    T = default_table_to_camera()
    m = _monitor(n_checks=1)
    parts = [PartSpec.cube("a", "red"), PartSpec.cube("b", "green"), PartSpec.cube("c", "blue")]
    m = ConnectionMonitor(parts, m.connections, AssemblyParams(N_checks=1))
    base = T @ Pose(np.array([0, A / 2, 0]))
    poses = {"a": base, "b": base @ Pose(np.array([0.2, 0, 0])), "c": base @ Pose(np.array([0, 0, A]))}
    m.update(0.0, poses, T)
    un = m.unexpected()
    assert [(u.first, u.second) for u in un] == [("a", "c")]
    assert any(not e.expected and e.type == "connected" for e in m.events)


def test_prior_survives_a_symmetric_jump_of_the_tracked_orientation():
    """The tracker may swap a cube's orientation for an equivalent one; the stored prior follows it."""
    pa = Pose.from_rt(R_FUND, [0, 0, 0.6])
    pb = Pose.from_rt(R_FUND, [A, 0, 0.6])
    pc = Pose.from_rt(R_FUND, [0, -A, 0.6])  # c on top of a
    st = SymmetryState({"a": True, "b": True, "c": True})
    st.establish("a", "b", _check(st, "a", "b", pa, pb, [A, 0, 0]), lambda o: True)
    jumped = Pose.from_rt(pa.R @ G[5], pa.t)  # same cube, another of its 24 equivalent orientations
    r = _check(st, "a", "b", jumped, pb, [A, 0, 0])
    assert r.case == 4
    np.testing.assert_allclose(r.best.p, [A, 0, 0], atol=1e-9)
    np.testing.assert_allclose(st.fundamental("a"), R_FUND, atol=1e-9)
    # a 20° drift about the vertical is absorbed as well (p rotates with the drift, F follows the tracker)
    drift = Pose.from_rt(Pose.from_rotvec(UP * np.radians(20), np.zeros(3)).R @ jumped.R, pa.t)
    r2 = _check(st, "a", "c", drift, pc, [0, A, 0])
    np.testing.assert_allclose(r2.best.p, [0, A, 0], atol=1e-9)


def test_tracker_yaw_and_tilt_errors_are_tolerated_but_directions_stay_distinct():
    T = default_table_to_camera()
    m = _monitor(n_checks=1)
    base = T @ Pose(np.array([0, A / 2, 0]))
    n = T.R[:, 1]
    err = Pose.from_rotvec(n * np.radians(25), np.zeros(3)).R @ Pose.from_rotvec(T.R[:, 0] * np.radians(10),
                                                                                  np.zeros(3)).R
    pa = Pose.from_rt(err @ base.R, base.t)  # a's orientation estimate is 25° off in yaw and tilted 10°
    pb = base @ Pose(np.array([A, 0, 0]))
    m.update(0.0, {"a": pa, "b": pb}, T)
    assert m.status[0].state == "connected"
    np.testing.assert_allclose(m.status[0].option.p, [A, 0, 0], atol=1e-6)
    # b in front of a (90° away from the established direction) does not satisfy it
    m2 = _monitor(n_checks=1)
    st = m2.symmetry
    m2.update(0.0, {"a": base, "b": pb}, T)
    assert st.has_prior("a")
    front = base @ Pose(np.array([0, 0, A]))
    m2.params.N_break = 1
    m2.update(0.1, {"a": Pose.from_rt(err @ base.R, base.t), "b": front}, T)
    assert m2.status[0].state == "open"


def test_first_cube_without_prior_tracked_44_degrees_off_still_connects():
    """A released cube is often tracked with a heading error near 45° (between two faces). Without a stored
    prior the first cube's heading follows the observed offset (free_yaw_tolerance_deg, default 180); with only
    the 40° tolerance the true connection is rejected."""
    T = default_table_to_camera()
    n = T.R[:, 1]
    base = T @ Pose(np.array([0, A / 2, 0]))
    pb = base @ Pose(np.array([A, 0, 0]))
    for yaw in (44.0, -44.0):
        bad = Pose.from_rotvec(n * np.radians(yaw), np.zeros(3)).R
        poses = {"a": Pose.from_rt(bad @ base.R, base.t), "b": pb}
        m = _monitor(n_checks=1)
        m.update(0.0, poses, T)
        assert m.status[0].state == "connected"
        strict = _monitor(n_checks=1)
        strict.params.free_yaw_tolerance_deg = 0.0
        strict.update(0.0, poses, T)
        assert strict.status[0].state != "connected"
    # the same for the second cube: b's tracked orientation 30° off in yaw and tilted 25° (levelled residual
    # beyond the 45° rotation margin before the modulo-90° face choice), a exact
    tilt = Pose.from_rotvec(T.R[:, 2] * np.radians(25), np.zeros(3)).R
    for yaw in (30.0, -30.0):
        bad = Pose.from_rotvec(n * np.radians(yaw), np.zeros(3)).R @ tilt
        poses = {"a": base, "b": Pose.from_rt(bad @ pb.R, pb.t)}
        m = _monitor(n_checks=1)
        m.update(0.0, poses, T)
        assert m.status[0].state == "connected"
    # tracked 45° off in yaw and tilted 20°: after levelling, the face chosen from the tracked rotation leaves
    # more than 45°; the default (180°) still follows the offset, a 45° bound does not
    tilted = Pose.from_rotvec(n * np.radians(45), np.zeros(3)).R @ Pose.from_rotvec(T.R[:, 0] * np.radians(20),
                                                                                    np.zeros(3)).R
    poses = {"a": Pose.from_rt(tilted @ base.R, base.t), "b": pb}
    m = _monitor(n_checks=1)
    m.update(0.0, poses, T)
    assert m.status[0].state == "connected"
    bounded = _monitor(n_checks=1)
    bounded.params.free_yaw_tolerance_deg = 45.0
    bounded.update(0.0, poses, T)
    assert bounded.status[0].state != "connected"
    # the heading freedom does not accept a diagonal grid neighbour (√2·a away, 45° off both faces)
    diag = base @ Pose(np.array([A, 0, A]))
    m = _monitor(n_checks=1)
    m.update(0.0, {"a": base, "b": diag}, T)
    assert m.status[0].state != "connected"


def test_new_cube_re_anchors_the_heading_of_a_vertical_component():
    """r–g is vertical (g on top of r) and established while r's tracked heading was 44° off, so the component's
    heading is 44° off. o joins r horizontally (case 3): its observed offset re-anchors the component, so the
    next horizontal connection r–y is accepted."""
    T = default_table_to_camera()
    n = T.R[:, 1]
    names = ("r", "g", "o", "y")
    parts = [PartSpec.cube(x, c) for x, c in zip(names, ("red", "green", "orange", "yellow"), strict=True)]
    specs = [ConnectionSpec("r", "g", np.array([0, A, 0]), np.eye(3)),
             ConnectionSpec("o", "r", np.array([A, 0, 0]), np.eye(3)),
             ConnectionSpec("r", "y", np.array([A, 0, 0]), np.eye(3))]
    base = T @ Pose(np.array([0, A / 2, 0]))
    bad = Pose.from_rotvec(n * np.radians(44), np.zeros(3)).R
    r_bad = Pose.from_rt(bad @ base.R, base.t)
    far = {"o": base @ Pose(np.array([-0.3, 0, 0])), "y": base @ Pose(np.array([0.3, 0, 0]))}
    m = ConnectionMonitor(parts, specs, AssemblyParams(N_checks=1))
    m.update(0.0, {"r": r_bad, "g": Pose.from_rt(bad @ base.R, (base @ Pose(np.array([0, A, 0]))).t), **far}, T)
    assert m.established == [True, False, False]
    poses = {"r": base, "g": base @ Pose(np.array([0, A, 0])), "o": base @ Pose(np.array([-A, 0, 0])), "y": far["y"]}
    m.update(0.1, poses, T)
    assert m.established == [True, True, False]
    m.update(0.2, dict(poses, y=base @ Pose(np.array([A, 0, 0]))), T)
    assert m.established == [True, True, True]
    np.testing.assert_allclose(m.status[2].option.p, [A, 0, 0], atol=1e-6)


def test_structural_priors_ignore_the_tracked_orientation_of_connected_cubes():
    """Once a–b is established, b's fundamental frame comes from the structure (F_b = F_a R_des): a 44° yaw
    error of b's tracked orientation does not spoil the next connection b–c."""
    T = default_table_to_camera()
    parts = [PartSpec.cube(n, c) for n, c in (("a", "red"), ("b", "green"), ("c", "blue"))]
    specs = [ConnectionSpec("a", "b", np.array([A, 0, 0]), np.eye(3)), ConnectionSpec("b", "c", np.array([A, 0, 0]),
                                                                                        np.eye(3))]
    m = ConnectionMonitor(parts, specs, AssemblyParams(N_checks=1))
    base = T @ Pose(np.array([0, A / 2, 0]))
    poses = {"a": base, "b": base @ Pose(np.array([A, 0, 0])), "c": base @ Pose(np.array([0.3, 0, 0]))}
    m.update(0.0, poses, T)
    assert m.established == [True, False]
    n = T.R[:, 1]
    bad = Pose.from_rotvec(n * np.radians(44), np.zeros(3)).R
    poses = dict(poses, b=Pose.from_rt(bad @ poses["b"].R, poses["b"].t), c=base @ Pose(np.array([2 * A, 0, 0])))
    m.update(0.1, poses, T)
    assert m.established == [True, True]
    np.testing.assert_allclose(m.status[1].option.p, [A, 0, 0], atol=1e-6)


def test_far_apart_parts_skip_the_search_and_get_no_particles():
    T = default_table_to_camera()
    m = _monitor(n_checks=1)
    base = T @ Pose(np.array([0, A / 2, 0]))
    for dx, far in ((0.2, True), (0.06, False)):
        assert m._far_apart(m.connections[0], base, base @ Pose(np.array([dx, 0, 0]))) == far
    m.update(0.0, {"a": base, "b": base @ Pose(np.array([0.2, 0, 0]))}, T)
    assert m.status[0].score == 0.0 and m.connection_hints() == []
    # the cheap path agrees with the full score: 0.5 / N_max is not reached there
    full = connection_score(np.array([A, 0, 0]), np.eye(3), np.array([0.2, 0, 0]), np.eye(3), 0.01, 3)
    assert allocate_particles(full, 9) == 0


def test_cross3_and_scalar_margins_equal_numpy_bit_for_bit():
    """cross3 is np.cross's float64 result exactly (also for float32 inputs and lists), other shapes go to
    np.cross; margins of a scalar equal the broadcast ones and refuse non-positive values."""
    from tracker.assembly.relations import cross3, margins

    rng = np.random.default_rng(5)
    for _ in range(200):
        u, v = rng.normal(size=3) * 10.0 ** rng.integers(-6, 6), rng.normal(size=3)
        assert np.array_equal(cross3(u, v), np.cross(u, v))
        assert np.array_equal(cross3(u.astype(np.float32), v), np.cross(u.astype(np.float32), v))
    assert np.array_equal(cross3([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]), [0.0, 0.0, 1.0])
    uv = rng.normal(size=(4, 3))
    assert np.array_equal(cross3(uv, uv[::-1]), np.cross(uv, uv[::-1]))
    assert np.array_equal(margins(0.004), np.broadcast_to(np.asarray(0.004, float), (3,)))
    assert np.array_equal(margins(2), [2.0, 2.0, 2.0]) and margins(2).dtype == np.float64
    with pytest.raises(ValueError):
        margins(0.0)


def test_norm3_equals_numpy_norm_bit_for_bit_and_scalar_margins_are_shared_read_only():
    """norm3 is np.linalg.norm's value exactly (contiguous vectors, a matrix's column, float32 and lists); the margins
    of a number are one read-only array, so a caller cannot change them for the others."""
    from tracker.assembly.relations import margins, norm3

    rng = np.random.default_rng(11)
    for _ in range(300):
        v = rng.normal(size=3) * 10.0 ** rng.integers(-8, 8)
        R = rng.normal(size=(3, 3))
        assert norm3(v) == np.linalg.norm(v) and norm3(R[:, 1]) == np.linalg.norm(R[:, 1])
        assert norm3(v.astype(np.float32)) == np.linalg.norm(v.astype(np.float32))
    assert norm3([3.0, 4.0, 0.0]) == 5.0 and norm3(np.zeros(3)) == 0.0
    m = margins(0.007)
    assert margins(0.007) is m and not m.flags.writeable
    with pytest.raises(ValueError):
        m[0] = 1.0
    assert np.array_equal(2.0 * margins(0.007), [0.014, 0.014, 0.014])
