"""Camera odometry (tracker.odometry): accuracy on short seeded simulated sequences with a moving camera, masks,
frames that cannot be measured, the TUM trajectory format, the trajectory errors and the ``odometry`` command."""

from __future__ import annotations

import numpy as np
import pytest

from app.cli import main
from tracker.evaluation.trajectory_errors import trajectory_errors
from tracker.frame import Frame
from tracker.geometry.pose import Pose
from tracker.odometry import CameraOdometry, OdometryConfig, make_odometry
from tracker.odometry.exclusion_mask import exclusion_mask
from tracker.odometry.se3 import exp_se3, log_se3
from tracker.odometry.tum_trajectory import read_tum, write_tum
from tracker.sources.recording import RecordingWriter
from tracker.sources.simulator import SimOptions, SimulatedTable


def _run(src: SimulatedTable, odo, n: int, use_hand: bool = True, start: int = 0):
    w0 = src.camera_pose_at(start).inverse()
    times, est, truth, results = [], [], [], []
    for i in range(start, start + n):
        f = src.render(i)
        hb = f.meta["groundtruth"]["hand_box"] if use_hand else None
        res = odo.step(f, exclusion_mask(f.depth.shape, hb) if hb is not None else None)
        results.append(res)
        times.append(res.timestamp)
        est.append(res.pose_world_camera)
        truth.append(w0 @ src.camera_pose_at(i))
    return trajectory_errors(np.array(times), est, truth, delta=0.5), results


def test_dense_odometry_follows_a_swaying_camera_within_a_millimetre():
    src = SimulatedTable("static", seed=1, options=SimOptions(camera_motion="sway"), n_frames=45)
    errs, results = _run(src, CameraOdometry(src.intrinsics), 45)
    assert all(r.ok for r in results)
    moved = max(float(np.linalg.norm((src.camera_pose_at(0).inverse() @ src.camera_pose_at(i)).t)) for i in range(45))
    assert moved > 0.005  # the camera really moved (several mm)
    assert errs.ate_rmse < 0.0015, errs
    assert errs.rot_rmse_deg < 0.15, errs
    assert errs.rpe_trans_per_s < 0.003, errs


def test_dense_odometry_with_a_hand_moving_parts_masks_the_hand():
    src = SimulatedTable("guess-1", seed=2, options=SimOptions(camera_motion="handheld"))
    # frames 40-84: the hand is in view, reaches for a part and carries it
    boxes = [src.render_clean(i)["hand_box"] for i in (40, 60, 84)]
    assert all(b is not None for b in boxes)
    errs, results = _run(src, CameraOdometry(src.intrinsics), 45, start=40)
    assert len(results) == 45 and all(r.ok for r in results)
    assert errs.ate_rmse < 0.003, errs
    assert errs.rot_rmse_deg < 0.3, errs


def test_frame_without_depth_is_extrapolated_at_constant_velocity_and_flagged():
    src = SimulatedTable("static", seed=0, options=SimOptions(camera_motion="handheld"), n_frames=8)
    odo = CameraOdometry(src.intrinsics)
    poses = [odo.step(src.render(i)).pose_world_camera for i in range(4)]
    f = src.render(4)
    blind = Frame(f.index, f.timestamp, f.color, None, f.intrinsics)
    res = odo.step(blind)
    assert not res.ok and "no depth" in res.message
    # constant velocity: the same step as between the last two measured poses
    step = poses[2].inverse() @ poses[3]
    expect = poses[3] @ step
    assert res.pose_world_camera.translation_error(expect) < 1e-9
    assert res.pose_world_camera.translation_error(poses[3]) > 0  # not just the last pose
    # the next frame with depth is measured again
    assert odo.step(src.render(5)).ok
    skipped = odo.skip(6 / 30.0, "unreadable")
    assert not skipped.ok and skipped.message == "unreadable"


def test_a_prior_pose_replaces_the_constant_velocity_prediction_after_a_wrong_step():
    """A wrong registration the odometry took makes its constant-velocity prediction run off: the next alignment then
    starts far away and either converges to a wrong pose or rejects the right one as a jump from the prediction,
    frame after frame (tuning seed 1 of guess-3 hand-held inside the tracker: 118 frames without a measured pose).
    A ``prior`` from a caller that knows the path (the fused odometry) replaces the prediction: the frame is measured
    right."""
    src = SimulatedTable("static", seed=0, options=SimOptions(camera_motion="handheld"), n_frames=8)
    w0 = src.camera_pose_at(0).inverse()

    def wrong_step(odo):
        for i in range(5):
            assert odo.step(src.render(i)).ok
        t, T = odo._motion.last
        bad = T.copy()
        bad[0, 3] += 0.045  # a 4.5 cm wrong step, taken as measured: the prediction now runs 4.5 cm per frame
        odo._motion.reset(t - 1 / 30.0, T)
        odo._motion.update(t, bad)

    truth = (w0 @ src.camera_pose_at(5)).as_matrix()
    odo = CameraOdometry(src.intrinsics, OdometryConfig.half_resolution())
    wrong_step(odo)
    res = odo.step(src.render(5))  # no prior (nor the checks of the next test): rejected, or a wrong pose
    assert not res.ok or res.pose_world_camera.translation_error(Pose.from_matrix(truth)) > 0.01
    odo = CameraOdometry(src.intrinsics)
    wrong_step(odo)
    near = truth.copy()
    near[:3, 3] += [0.001, -0.001, 0.0]  # a prior a millimetre off
    res = odo.step(src.render(5), prior=near)
    assert res.ok, res.message
    assert res.pose_world_camera.translation_error(Pose.from_matrix(truth)) < 0.001


def test_a_fast_prediction_is_checked_by_an_alignment_from_the_last_pose():
    """A velocity gone wrong (one wrong registration's, here set by hand: 6 cm per frame while the last pose is right)
    puts the prediction near a wrong minimum of the alignment (on this plank-textured table 7 cm along x, 4283 inliers
    against 4800-4900 at the true pose), which is plausible as seen from the prediction: without a check the frame is
    taken there and the velocity runs on (tuning session guess-3 sway seed 3: 16.6 mm ATE). A predicted motion of more
    than ``second_start_m`` / ``second_start_deg`` per frame makes the odometry align the frame from the last pose
    too and keep the result with more inliers: the frame is measured right and the velocity re-estimated."""
    src = SimulatedTable("static", seed=0, options=SimOptions(camera_motion="handheld"), n_frames=8)
    w0 = src.camera_pose_at(0).inverse()
    truth = Pose.from_matrix((w0 @ src.camera_pose_at(5)).as_matrix())

    def run(config: OdometryConfig):
        odo = CameraOdometry(src.intrinsics, config)
        for i in range(5):
            assert odo.step(src.render(i)).ok
        t, T = odo._motion.last
        back = T.copy()
        back[0, 3] -= 0.06
        odo._motion.reset(t - 1 / 30.0, back)
        odo._motion.update(t, T)  # the last pose right, the velocity 6 cm per frame along x
        return odo, odo.step(src.render(5))

    _, res = run(OdometryConfig(second_start_m=0.0, second_start_deg=0.0))
    assert not res.ok or res.pose_world_camera.translation_error(truth) > 0.01
    odo, res = run(OdometryConfig())
    assert res.ok, res.message
    assert res.pose_world_camera.translation_error(truth) < 0.001
    assert odo.step(src.render(6)).ok  # and the next frame, from the re-estimated velocity


def test_a_frame_mostly_hidden_by_hands_does_not_become_a_keyframe():
    """The hands hide what fixes a frame's pose, and a keyframe keeps its pose's error for every later frame: a frame
    with more than ``keyframe_max_masked`` of its pixels masked is not taken as a keyframe while it still sees the
    old one (tuning session guess-1 hand-held 2 at 5x speed: a 34 mm error kept to the end)."""
    src = SimulatedTable("static", seed=1, options=SimOptions(camera_motion="sway"), n_frames=8)
    h, w = src.intrinsics.height, src.intrinsics.width
    half = np.zeros((h, w), bool)
    half[:, : w // 2] = True  # half the image masked
    sliver = np.zeros((h, w), bool)
    sliver[:, : w // 10] = True
    cfg = OdometryConfig(keyframe_distance_m=1e-6)  # every frame would be a keyframe
    odo = CameraOdometry(src.intrinsics, cfg)
    taken = [odo.step(src.render(i), half if i else None).keyframe for i in range(4)]
    assert taken == [True, False, False, False] and len(odo.keyframes) == 1
    assert odo.step(src.render(4), sliver).keyframe and len(odo.keyframes) == 2
    odo = CameraOdometry(src.intrinsics, cfg.with_overrides(keyframe_max_masked=1.0))
    assert [odo.step(src.render(i), half if i else None).keyframe for i in range(4)] == [True] * 4


def test_mask_of_wrong_shape_and_frame_of_wrong_size_are_refused():
    src = SimulatedTable("static", seed=0, n_frames=2)
    odo = CameraOdometry(src.intrinsics)
    f = src.render(0)
    with pytest.raises(ValueError, match="mask shape"):
        odo.step(f, np.zeros((10, 10), bool))
    small = src.intrinsics.scaled(0.5)
    g = Frame(0, 0.0, np.zeros((small.height, small.width, 3), np.uint8), None, small)
    with pytest.raises(ValueError, match="set up for 640x480"):
        odo.step(g)


def test_exclusion_mask_covers_hand_box_and_dilated_parts():
    part = np.zeros((60, 80), np.uint8)
    part[10:14, 10:14] = 255
    m = exclusion_mask((60, 80), hand_box=[50, 30, 60, 40], part_masks=[part], margin=2)
    assert m[12, 12] and m[12, 15] and not m[12, 17]  # dilated by 2 px
    assert m[35, 55] and m[29, 49] and not m[26, 45]
    with pytest.raises(ValueError):
        exclusion_mask((60, 80), part_masks=[np.zeros((5, 5))])


def test_se3_exp_log_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(20):
        xi = rng.normal(size=6) * np.array([0.1, 0.1, 0.1, 0.5, 0.5, 0.5])
        assert np.allclose(log_se3(exp_se3(xi)), xi, atol=1e-9)


def test_tum_round_trip_and_errors(tmp_path):
    rng = np.random.default_rng(3)
    rows = [(i / 30.0, Pose.from_rotvec(rng.normal(size=3) * 0.1, rng.normal(size=3)), "note" if i == 2 else "")
            for i in range(5)]
    path = tmp_path / "t.tum"
    assert write_tum(path, rows, header="test") == 5
    text = path.read_text().splitlines()
    assert text[0] == "# test" and "# note" in text
    times, poses = read_tum(path)
    assert np.allclose(times, [r[0] for r in rows], atol=1e-6)
    for p, r in zip(poses, rows, strict=True):
        assert p.translation_error(r[1]) < 1e-8 and p.rotation_error(r[1]) < 1e-7
    bad = tmp_path / "bad.tum"
    bad.write_text("0.0 1 2 3 0 0 0\n")
    with pytest.raises(ValueError, match="line 1: expected 8 numbers"):
        read_tum(bad)


def test_trajectory_errors_of_a_known_offset():
    times = np.arange(31) / 30.0
    truth = [Pose.from_rotvec([0, 0.01 * i, 0], [0.001 * i, 0, 0]) for i in range(31)]
    est = [p @ Pose(t=[0.002, 0, 0]) for p in truth]  # constant 2 mm offset in the camera frame
    e = trajectory_errors(times, est, truth, delta=0.5)
    assert abs(e.ate_rmse - 0.002) < 1e-9 and e.rot_rmse_deg < 1e-6
    assert e.rpe_trans_per_s < 1e-3  # a constant offset is no relative error (up to the rotation's lever arm)
    drift = [p @ Pose(t=[0.003 * i, 0, 0]) for i, p in enumerate(truth)]  # 3 mm per frame = 90 mm/s
    assert abs(trajectory_errors(times, drift, truth, delta=1.0).rpe_trans_per_s - 0.09) < 1e-6
    with pytest.raises(ValueError):
        trajectory_errors(times[:3], est, truth)


def test_make_odometry_refuses_unknown_method():
    with pytest.raises(ValueError, match="default, fastslam"):
        make_odometry("orb", SimulatedTable("static", n_frames=1).intrinsics)
    with pytest.raises(ValueError, match="unknown setting"):
        OdometryConfig().with_overrides(levels_=1)


def _sway_recording(rec, n: int, no_depth_at: int) -> SimulatedTable:
    """A static scene seen by a swaying camera, ``n`` frames written to ``rec``, frame ``no_depth_at`` without
    depth; returns the simulator (its camera poses are the truth)."""
    src = SimulatedTable("static", seed=0, options=SimOptions(camera_motion="sway"), n_frames=n)
    with RecordingWriter(rec, src.intrinsics, parts=src.parts, initial_poses=src.initial_poses) as w:
        for i in range(n):
            f = src.render(i)
            if i == no_depth_at:
                f = Frame(f.index, f.timestamp, f.color, None, f.intrinsics, f.meta)
            w.write(f, f.meta["groundtruth"])
    return src


def test_odometry_command_writes_a_pose_per_frame_and_survives_bad_frames(tmp_path, capsys):
    rec = tmp_path / "rec"
    src = _sway_recording(rec, 12, 5)
    (rec / "color" / "000008.png").write_bytes(b"not a png")
    out = tmp_path / "traj.tum"
    assert main(["odometry", str(rec), "--out", str(out), "--mask", "parts"]) == 0
    captured = capsys.readouterr()
    assert "wrote 12 poses" in captured.out and "(2 extrapolated)" in captured.out
    assert "no depth" in captured.err and "000008.png" in captured.err
    assert "ATE RMSE" in captured.out
    times, poses = read_tum(out)
    assert len(poses) == 12 and np.allclose(times, np.arange(12) / 30.0, atol=1e-6)
    assert sum(1 for line in out.read_text().splitlines() if line.startswith("# extrapolated")) == 2
    w0 = src.camera_pose_at(0).inverse()
    assert max(p.translation_error(w0 @ src.camera_pose_at(i)) for i, p in enumerate(poses)) < 0.003


def test_odometry_command_masks_the_hands_it_finds_when_the_recording_has_no_hand_boxes(tmp_path):
    """A real camera's recording has no ground-truth hand boxes: ``--mask hand`` then masks the hands that the hand
    tracker finds in the images (hand, bare forearm, box; :mod:`tracker.odometry.hand_exclusion`). A hand-held
    camera over a hand that picks up and carries a part (frames 40-89): within a millimetre everywhere with the
    mask, several millimetres off where the hand is with none."""
    from app.commands.odometry import estimate_trajectory

    rec = tmp_path / "rec"
    n = 90
    src = SimulatedTable("guess-1", seed=2, options=SimOptions(camera_motion="handheld"), n_frames=n)
    with RecordingWriter(rec, src.intrinsics, parts=src.parts, initial_poses=src.initial_poses) as w:
        for i in range(n):
            f = src.render(i)
            truth = dict(f.meta["groundtruth"])
            del truth["hand_box"]  # as a real recording: camera poses known (to measure), hands not
            w.write(f, truth)
    assert src.render_clean(60)["hand_box"] is not None
    masked = estimate_trajectory(str(rec), "default", "hand").errors()
    bare = estimate_trajectory(str(rec), "default", "none").errors()
    assert masked["ate_max_mm"] < 2.0, masked
    assert bare["ate_max_mm"] > 2 * masked["ate_max_mm"] and bare["ate_max_mm"] > 4.0, bare


def test_odometry_command_parts_method_follows_a_swaying_camera_from_the_resting_parts(tmp_path, capsys):
    """``--method parts``: the camera pose from the recording's resting cubes, within a millimetre on a swaying
    camera; a frame without depth keeps the last pose and is flagged."""
    rec = tmp_path / "rec"
    src = _sway_recording(rec, 40, 20)
    out = tmp_path / "traj.tum"
    assert main(["odometry", str(rec), "--out", str(out), "--method", "parts"]) == 0
    captured = capsys.readouterr()
    assert "wrote 40 poses" in captured.out and "(1 extrapolated)" in captured.out
    assert "no depth" in captured.err
    _, poses = read_tum(out)
    w0 = src.camera_pose_at(0).inverse()
    errs = [p.translation_error(w0 @ src.camera_pose_at(i)) for i, p in enumerate(poses)]
    moved = max(Pose().translation_error(w0 @ src.camera_pose_at(i)) for i in range(40))
    assert moved > 0.005  # the camera really moves
    assert max(errs[:20] + errs[21:]) < 0.001, max(errs)


def test_odometry_command_fused_method_follows_a_swaying_camera(tmp_path, capsys):
    """``--method fused``: dense odometry and resting cubes together, within a millimetre on a swaying camera; a
    frame without depth is predicted and flagged."""
    rec = tmp_path / "rec"
    src = _sway_recording(rec, 30, 15)
    out = tmp_path / "traj.tum"
    assert main(["odometry", str(rec), "--out", str(out), "--method", "fused"]) == 0
    captured = capsys.readouterr()
    assert "wrote 30 poses" in captured.out and "(1 extrapolated)" in captured.out
    _, poses = read_tum(out)
    w0 = src.camera_pose_at(0).inverse()
    errs = [p.translation_error(w0 @ src.camera_pose_at(i)) for i, p in enumerate(poses)]
    assert max(Pose().translation_error(w0 @ src.camera_pose_at(i)) for i in range(30)) > 0.005
    assert max(errs) < 0.001, max(errs)


def test_odometry_command_reports_a_missing_recording(tmp_path, capsys):
    assert main(["odometry", str(tmp_path / "nope"), "--out", str(tmp_path / "t.tum")]) == 1
    assert "recording directory not found" in capsys.readouterr().err


def test_fastslam_filter_prefers_the_particle_at_the_true_pose():
    from tracker.odometry.fastslam import FastSlam1, FastSlamConfig, sus_indices

    rng = np.random.default_rng(0)
    flt = FastSlam1(525.0, FastSlamConfig(n_particles=3), rng)
    pts = rng.uniform([-0.3, -0.2, 0.5], [0.3, 0.2, 1.0], (40, 3))
    flt.add_landmarks(pts)
    flt.t[1] = [0.004, 0.0, 0.0]  # particle 1 believes it moved 4 mm, particle 2 turned 0.5°
    flt.R[2] = exp_se3([0, 0, 0, 0, np.radians(0.5), 0])[:3, :3]
    before = flt.sigma[0, 0].copy()
    flt.update(pts, np.arange(40))
    w = flt.weights()
    assert w[0] > 0.99 and np.argmax(w) == 0
    assert np.trace(flt.sigma[0, 0]) < np.trace(before)  # the landmark became more certain
    R, t = flt.estimate()
    assert np.linalg.norm(t) < 1e-4 and np.allclose(R, np.eye(3), atol=1e-4)
    # SUS draws particles in proportion to their weights
    idx = sus_indices(np.array([0.5, 0.25, 0.25, 0.0]), rng)
    assert sorted(idx.tolist()) == [0, 0, 1, 2]


def test_fastslam_odometry_follows_a_swaying_camera_within_centimetres():
    src = SimulatedTable("static", seed=0, options=SimOptions(camera_motion="sway"), n_frames=30)
    odo = make_odometry("fastslam", src.intrinsics, seed=0)
    errs, results = _run(src, odo, 30)
    assert all(r.ok for r in results) and min(r.inliers for r in results[1:]) >= 8
    assert odo.filter.n_landmarks > 20
    assert errs.ate_rmse < 0.01, errs
    assert errs.rot_rmse_deg < 1.0, errs


def test_rigid_transforms_agree_with_scipy_and_invert_each_other():
    """One SE(3) implementation (compiled, tracker/odometry/se3.py) for the Gauss-Newton loop and the Python
    callers: its rotation is scipy's of the same rotation vector, log inverts exp, invert inverts."""
    from scipy.spatial.transform import Rotation

    from tracker.odometry.se3 import invert

    rng = np.random.default_rng(3)
    for xi in [np.zeros(6), np.r_[0.01, -0.02, 0.005, 1e-12, 0.0, 0.0], *rng.normal(scale=0.3, size=(5, 6))]:
        T = exp_se3(xi)
        assert np.allclose(T[:3, :3], Rotation.from_rotvec(xi[3:]).as_matrix(), atol=1e-12)
        assert np.allclose(T[3], [0.0, 0.0, 0.0, 1.0])
        assert np.allclose(log_se3(T), xi, atol=1e-9)
        assert np.allclose(invert(T) @ T, np.eye(4), atol=1e-12)


def test_pyramid_halves_depth_and_mask_and_drops_blocks_with_a_hole_or_an_edge():
    from tracker.geometry.camera import Intrinsics
    from tracker.odometry.rgbd_pyramid import build_pyramid

    depth = np.full((8, 8), 0.5, np.float32)
    depth[0, 0] = np.nan  # a hole: block (0, 0) invalid
    depth[0, 3] = 0.0  # no measurement: block (0, 1) invalid
    depth[2:4, 4:6] = [[0.5, 0.6], [0.5, 0.6]]  # an occlusion edge inside block (1, 2): invalid
    depth[4:6, 0:2] = [[0.50, 0.504], [0.502, 0.506]]  # a slope within the spread: averaged
    mask = np.zeros((8, 8), bool)
    mask[7, 7] = True
    rgb = np.zeros((8, 8, 3), np.uint8)
    pyr = build_pyramid(rgb, depth, Intrinsics.default(8, 8), 3, mask, first_level=1)
    assert pyr[0] is None  # not asked for
    d1 = pyr[1].depth
    assert d1.shape == (4, 4) and np.isnan(d1[0, 0]) and np.isnan(d1[0, 1]) and np.isnan(d1[1, 2])
    assert d1[2, 0] == pytest.approx(0.503, abs=1e-6) and d1[3, 3] == pytest.approx(0.5)
    assert pyr[1].mask[3, 3] and pyr[1].mask.sum() == 1
    assert pyr[2].mask[1, 1] and pyr[2].mask.sum() == 1 and np.isnan(pyr[2].depth[0, 0])
    assert pyr[2].intrinsics.width == 2


def test_fused_odometry_with_its_camera_path_in_a_process_equals_one_step_after_the_other(tmp_path, monkeypatch):
    """The fused command runs the camera's path (frame k's dense step beside frame k's tracker step, frame k's fusion
    beside frame k + 1's) in a child process (frames through shared memory); the trajectory, its flagged frames (a
    skipped one included) and their order are the same to the last bit as with every job run at once in the calling
    thread (no shared state, no write to the frame)."""
    from app.commands import odometry as odometry_command

    rec = tmp_path / "rec"
    _sway_recording(rec, 12, 6)
    assert odometry_command.FUSED_PATH_PROCESS
    threaded = odometry_command.estimate_trajectory(str(rec), "fused")
    monkeypatch.setattr(odometry_command, "FUSED_PATH_PROCESS", False)
    inline = odometry_command.estimate_trajectory(str(rec), "fused")
    assert len(threaded.rows) == len(inline.rows) == 12 and threaded.flagged == inline.flagged == 1
    for (ta, pa, ca), (tb, pb, cb) in zip(threaded.rows, inline.rows, strict=True):
        assert ta == tb and ca == cb
        assert np.array_equal(pa.t, pb.t) and np.array_equal(pa.q, pb.q)
    assert threaded.errors()["ate_rmse_mm"] < 1.0


def test_camera_path_process_reports_a_child_that_cannot_start_and_a_job_that_fails(tmp_path):
    """The fused odometry's child process: one that cannot start fails with the child's reason; a job that fails in
    the child fails that frame's future (the parent raises it) and the child keeps serving; more frames than its
    shared-memory slots go through (the parent waits for a slot's frame to be fused before writing it again)."""
    from app.commands.camera_path import SLOTS, CameraPathProcess
    from tracker.sources.recording import RecordingSource

    rec = tmp_path / "rec"
    _sway_recording(rec, SLOTS + 3, None)
    src = RecordingSource(str(rec), prefetch=0)
    frames = [src.read(i) for i in range(len(src))]
    src.close()
    with pytest.raises(RuntimeError, match="cannot start the camera path process: ValueError"):
        CameraPathProcess(src.intrinsics, -1, {})  # a negative seed: the child's random generator refuses it
    path = CameraPathProcess(src.intrinsics, 0, {})
    try:
        with pytest.raises(ValueError, match="a frame of"):
            path.dense(frames[0], np.zeros((4, 4), bool))
        results = []
        for i, frame in enumerate(frames):
            path.dense(frame, None)
            # frame 1's fusion fails in the child: a landmark without corners, a landmark since frame 0
            results.append(path.fuse({"ghost": "not a pose"} if i < 2 else {}, None))
        with pytest.raises(RuntimeError, match="camera path, fuse: KeyError"):
            results[1].result(timeout=60)
        for i in (0, *range(2, len(frames))):
            assert results[i].result(timeout=60).timestamp == pytest.approx(frames[i].timestamp)
    finally:
        path.close()
