"""Quiet parts (filter/quiet_parts.py): a resting, well-seen part skips its coordinate pass; one whose blob moves
otherwise than its prediction, or changes its area, does not."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tracker.filter.tracker_config import TrackerConfig


def _session(quiet: bool, frames: int = 25):
    """The simulator's ``static`` scene (five cubes at rest, fixed camera, no hand), tracked ``frames`` frames as
    ``assembly-agent track`` tracks it. Returns the session, the last frame's detections and the per-frame worst
    translation error (m)."""
    from app.commands.track import TrackSession
    from tracker.sources.simulator import SimulatedTable

    src = SimulatedTable("static", seed=3, realtime=False, n_frames=frames)
    # the blob and refinement tests alone (the depth test, quiet_max_residual_m, is tested on its own below)
    cfg = TrackerConfig.preset("default").with_overrides(quiet_skip=quiet, quiet_max_residual_m=0.0)
    ts = TrackSession(src.parts, src.intrinsics, src.initial_poses, cfg, seed=0)
    errors = []
    dets = None
    for i in range(frames):
        frame = src.render(i)
        dets = ts.detector.detect(frame.color)
        state, _ = ts.step(frame)
        truth = frame.meta["groundtruth"]["poses"]
        errors.append(max(float(np.linalg.norm(state.poses[n].t - truth[n].t)) for n in state.poses))
    ts.last_frame = frame  # the depth test of quiet_max_residual_m looks at it
    return ts, dets, np.array(errors)


@pytest.fixture(scope="module")
def quiet_run():
    return _session(True)


def test_resting_parts_skip_passes_and_stay_as_precise(quiet_run):
    ts, _, err_quiet = quiet_run
    trk = ts.tracker
    k = len(trk.parts)
    assert trk.n_quiet_skipped > 0.3 * k * 25  # most passes of five resting cubes are skipped
    assert trk.n_quiet_skipped <= 0.75 * k * 25  # at most 3 in a row: every 4th pass runs
    _, _, err_full = _session(False)
    assert err_quiet[5:].max() < 0.004
    assert np.median(err_quiet[5:]) <= np.median(err_full[5:]) + 0.0005


def test_off_skips_nothing():
    ts, _, _ = _session(False, frames=6)
    assert ts.tracker.n_quiet_skipped == 0


def test_a_blob_that_moves_or_changes_its_area_is_not_quiet(quiet_run):
    from tracker.filter import predict, quiet_parts
    from tracker.filter.frame_context import FrameContext

    ts, dets, _ = quiet_run
    trk = ts.tracker
    memory = trk._quiet_memory
    assert memory is not None

    def decide(detections):
        trk._quiet_memory = memory
        trk._quiet_skips[:] = 0
        ctx = FrameContext(frame=ts.last_frame, table=None, table_plane=None, t0=0.0)
        pred = predict.deterministic(trk, np.zeros((len(trk.parts), 3)))
        return quiet_parts.quiet_parts(trk, ctx, detections, np.ones(len(trk.parts), bool), pred)

    same = decide(dets)
    assert same.sum() >= 3  # the last frame's own blobs: resting parts are quiet
    name = next(n for i, n in enumerate(trk.names) if same[i])
    i = trk.names.index(name)
    d = dets[name]
    shifted = dict(dets)
    shifted[name] = dataclasses.replace(d, center=(d.center[0] + 4.0, d.center[1]))
    moved = decide(shifted)
    assert not moved[i]
    assert moved.sum() == same.sum() - 1  # the others stay quiet
    grown = dict(dets)
    grown[name] = dataclasses.replace(d, area=d.area * 1.3)
    assert not decide(grown)[i]
    trk._quiet_skips[:] = trk.config.quiet_max_skips
    trk._quiet_memory = memory
    ctx = FrameContext(frame=ts.last_frame, table=None, table_plane=None, t0=0.0)
    pred = predict.deterministic(trk, np.zeros((len(trk.parts), 3)))
    assert not quiet_parts.quiet_parts(trk, ctx, dets, np.ones(len(trk.parts), bool), pred).any()  # a pass is due


def test_a_quiet_part_is_evaluated_on_fewer_pixels():
    """quiet_pixels_per_part: the part whose pass is skipped keeps a coarser lattice of likelihood pixels; the
    others keep theirs."""
    from tracker.filter import render
    from tracker.filter.particle_filter import MultiObjectTracker
    from tracker.geometry.camera import Intrinsics
    from tracker.geometry.parts import PartSpec
    from tracker.geometry.pose import Pose

    intr = Intrinsics(640, 480, 600.0, 600.0, 320.0, 240.0)
    parts = [PartSpec.cube(c, c) for c in ("red", "green")]
    depth = np.full((480, 640), 0.3, np.float32)  # valid everywhere
    counts = {}
    for quiet_px in (0, 40):
        cfg = TrackerConfig.preset("default").with_overrides(n_particles=20, likelihood_pixels_per_part=250,
                                                             quiet_pixels_per_part=quiet_px)
        trk = MultiObjectTracker(parts, intr, cfg, seed=0)
        trk.initialize({"red": Pose([-0.06, 0.0, 0.25], [0, 0, 0, 1]), "green": Pose([0.06, 0.0, 0.25], [0, 0, 0, 1])})
        trk._quiet_now = np.array([True, False])
        pix, regions = render.evaluated_pixels(trk, depth, trk.p, trk.R, trk.p, trk.R)
        counts[quiet_px] = (int(np.count_nonzero(regions[0])), int(np.count_nonzero(regions[1])), trk._lattice.copy())
    full, quiet = counts[0], counts[40]
    assert full[0] > 150 and full[1] > 150
    assert quiet[0] < full[0] / 3  # the quiet part: about its own budget (plus the other part's pixels it overlaps)
    assert quiet[1] == full[1]  # the other part: unchanged
    assert quiet[2][0] > full[2][0] and quiet[2][1] == full[2][1]


def test_depth_explained_sees_a_hand_over_the_part_and_a_moved_part():
    """The depth test of ``quiet_max_residual_m``: a cube's depth at its pose is explained; a hand-like slab in front of
    half of it, or the cube pushed 1 cm, is not; nor is a frame without depth there."""
    from tracker.filter.quiet_parts import depth_explained, face_points
    from tracker.geometry.box_renderer import render_box_depth
    from tracker.geometry.camera import Intrinsics
    from tracker.geometry.pose import Pose

    intr = Intrinsics(640, 480, 600.0, 600.0, 320.0, 240.0)
    ang = np.radians(35.0)  # turned about x and y: three faces to the camera
    rx = np.array([[1, 0, 0], [0, np.cos(ang), -np.sin(ang)], [0, np.sin(ang), np.cos(ang)]])
    ry = np.array([[np.cos(ang), 0, np.sin(ang)], [0, 1, 0], [-np.sin(ang), 0, np.cos(ang)]])
    rot = ry @ rx
    t = np.array([0.02, -0.01, 0.6])
    size = 0.036
    depth = render_box_depth(intr, [Pose.from_rt(rot, t)], [(size, size, size)]).astype(np.float32)
    depth[~np.isfinite(depth)] = 0.9  # a table far behind
    rng = np.random.default_rng(0)
    depth += rng.normal(0.0, 0.001, depth.shape).astype(np.float32)
    faces = face_points(np.full(3, size / 2), np.zeros(3))
    assert faces.shape == (96, 6)
    assert depth_explained(depth, intr, faces, rot, t, 0.005, 0.85)
    u = int(round(600.0 * t[0] / t[2] + 320.0))
    hand = depth.copy()
    hand[:, u:] = np.minimum(hand[:, u:], 0.55)  # a hand 5 cm in front of the cube's right half
    assert not depth_explained(hand, intr, faces, rot, t, 0.005, 0.85)
    assert not depth_explained(depth, intr, faces, rot, t + np.array([0.0, 0.0, 0.01]), 0.005, 0.85)
    holes = depth.copy()
    holes[:, :] = np.nan
    assert not depth_explained(holes, intr, faces, rot, t, 0.005, 0.85)
    assert not depth_explained(None, intr, faces, rot, t, 0.005, 0.85)


def _run(overrides: dict, frames: int = 24):
    """The ``static`` scene of :func:`_session` tracked with these TrackerConfig overrides; returns the session, the
    per-frame quiet parts (frames, K) and the per-frame worst translation (m) and rotation (deg) errors."""
    from app.commands.track import TrackSession
    from tracker.geometry.symmetry import symmetric_rotation_error, symmetry_group
    from tracker.sources.simulator import SimulatedTable

    src = SimulatedTable("static", seed=3, realtime=False, n_frames=frames)
    cfg = TrackerConfig.preset("default").with_overrides(**overrides)
    ts = TrackSession(src.parts, src.intrinsics, src.initial_poses, cfg, seed=0)
    groups = {p.name: symmetry_group(p) for p in src.parts}
    settled, t_err, r_err = [], [], []
    for i in range(frames):
        frame = src.render(i)
        state, _ = ts.step(frame)
        settled.append(ts.tracker._settled.copy())
        truth = frame.meta["groundtruth"]["poses"]
        t_err.append(max(float(np.linalg.norm(state.poses[n].t - truth[n].t)) for n in state.poses))
        r_err.append(max(np.degrees(float(symmetric_rotation_error(state.poses[n].R, truth[n].R, groups[n])))
                         for n in state.poses))
    return ts, np.array(settled), np.array(t_err), np.array(r_err)


LIGHT = {"quiet_refine_skip": True, "quiet_refine_hold": True, "quiet_thin": True, "quiet_pixels_per_part": 60,
         "quiet_max_residual_m": 0.005}
"""The lighter quiet settings together: a quiet part keeps its pass on fewer pixels and is held at its prediction
instead of refined."""


def test_held_quiet_parts_are_refined_every_other_frame_and_stay_precise():
    ts, settled, t_err, r_err = _run(LIGHT)
    k = settled.shape[1]
    assert ts.tracker.n_quiet_skipped == 0  # no pass is skipped
    # resting cubes whose faces the depth shows (2 of the 5: touching neighbours hide the others' face points) are
    # quiet on about every other frame
    assert settled.sum() >= 0.1 * k * settled.shape[0]
    assert not (settled[1:] & settled[:-1]).any()  # a held part has no correction to remember: refined next frame
    _, off, t_full, r_full = _run({})
    assert not off.any()
    assert t_err[5:].max() < 0.003 and r_err[5:].max() < 3.0
    assert np.median(t_err[5:]) <= np.median(t_full[5:]) + 0.0005
    assert np.median(r_err[5:]) <= np.median(r_full[5:]) + 0.5


def test_quiet_thin_evaluates_a_quiet_part_on_fewer_pixels_without_skipping_it():
    """quiet_thin: a quiet part (``_settled``) whose pass runs gets the quiet pixel budget; without quiet_thin only a
    part whose pass is skipped does."""
    from tracker.filter import render
    from tracker.filter.particle_filter import MultiObjectTracker
    from tracker.geometry.camera import Intrinsics
    from tracker.geometry.parts import PartSpec
    from tracker.geometry.pose import Pose

    intr = Intrinsics(640, 480, 600.0, 600.0, 320.0, 240.0)
    parts = [PartSpec.cube(c, c) for c in ("red", "green")]
    depth = np.full((480, 640), 0.3, np.float32)
    lattices = {}
    for thin in (False, True):
        cfg = TrackerConfig.preset("default").with_overrides(n_particles=20, likelihood_pixels_per_part=250,
                                                             quiet_pixels_per_part=40, quiet_thin=thin)
        trk = MultiObjectTracker(parts, intr, cfg, seed=0)
        trk.initialize({"red": Pose([-0.06, 0.0, 0.25], [0, 0, 0, 1]), "green": Pose([0.06, 0.0, 0.25], [0, 0, 0, 1])})
        trk._quiet_now = np.array([False, False])
        trk._settled = np.array([True, False])
        render.evaluated_pixels(trk, depth, trk.p, trk.R, trk.p, trk.R)
        lattices[thin] = trk._lattice.copy()
    assert lattices[True][0] > lattices[False][0]
    assert lattices[True][1] == lattices[False][1]


def test_quiet_refine_last_refines_a_quiet_part_on_the_finest_thresholds(monkeypatch):
    from tracker.filter.particle_filter import MultiObjectTracker
    from tracker.geometry.camera import Intrinsics
    from tracker.geometry.parts import PartSpec
    from tracker.geometry.pose import Pose
    from tracker.refine import part_refiner

    intr = Intrinsics(640, 480, 600.0, 600.0, 320.0, 240.0)
    parts = [PartSpec.cube(c, c) for c in ("red", "green")]
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=20, quiet_refine_last=2)
    trk = MultiObjectTracker(parts, intr, cfg, seed=0)
    refiner = trk._refiner
    assert refiner.short_settings.thresholds == tuple(cfg.refine_thresholds)[-2:]
    seen = {}
    real = part_refiner.refine_pose

    def spy(depth, intrinsics, pts, nrm, R0, t0, center, settings, *rest):
        seen[round(float(t0[0]), 2)] = settings.thresholds
        return real(depth, intrinsics, pts, nrm, R0, t0, center, settings, *rest)

    monkeypatch.setattr(part_refiner, "refine_pose", spy)
    poses = [Pose([-0.06, 0.0, 0.3], [0, 0, 0, 1]), Pose([0.06, 0.0, 0.3], [0, 0, 0, 1])]
    depth = np.full((480, 640), 0.33, np.float32)
    refiner.refine(depth, [(p.R, p.t) for p in poses], [True, True], short=[True, False])
    assert seen == {-0.06: tuple(cfg.refine_thresholds)[-2:], 0.06: tuple(cfg.refine_thresholds)}


def _held_moves(last: bool, frames: int = 24):
    """The ``static`` scene (fixed camera) with a quiet part held every other frame (``quiet_refine_hold_last``
    set to ``last``): per held part-frame, how far (m) its final estimate lies from the frame before's; and the
    per-frame worst errors."""
    from app.commands.track import TrackSession
    from tracker.sources.simulator import SimulatedTable

    src = SimulatedTable("static", seed=3, realtime=False, n_frames=frames)
    cfg = TrackerConfig.preset("default").with_overrides(quiet_refine_skip=True, quiet_refine_hold=True,
                                                         quiet_refine_hold_last=last, quiet_max_residual_m=0.005)
    ts = TrackSession(src.parts, src.intrinsics, src.initial_poses, cfg, seed=0)
    moves, t_err, before = [], [], None
    for i in range(frames):
        frame = src.render(i)
        state, _ = ts.step(frame)
        truth = frame.meta["groundtruth"]["poses"]
        t_err.append(max(float(np.linalg.norm(state.poses[n].t - truth[n].t)) for n in state.poses))
        for k in np.flatnonzero(ts.tracker._settled):
            name = ts.tracker.names[k]
            moves.append(float(np.linalg.norm(state.poses[name].t - before[name].t)))
        before = dict(state.poses)
    return np.array(moves), np.array(t_err)


def test_quiet_refine_hold_last_holds_a_quiet_part_where_it_rested():
    """quiet_refine_hold_last: a held part keeps last frame's estimate (the camera is fixed: nothing moves it);
    held at its constant-velocity prediction instead (the setting explicitly off) it moves by that prediction."""
    moves, t_err = _held_moves(True)
    assert moves.size >= 10
    assert moves.max() < 1e-9
    assert t_err[5:].max() < 0.003
    moves_off, _ = _held_moves(False)
    assert moves_off.size >= 10
    assert moves_off.max() > 1e-6


HELD = {"quiet_skip": True, "quiet_refine_skip": True, "quiet_refine_hold": True, "quiet_refine_hold_last": True,
        "quiet_max_residual_m": 0.005}
"""A quiet part's pass skipped and the part held at its last estimate instead of refined."""


def _skips(overrides: dict, frames: int = 24):
    """The ``static`` scene of :func:`_run` with these overrides: per frame the parts whose pass is skipped and those
    held (not refined), (frames, K) each; and the per-frame worst translation error (m)."""
    from app.commands.track import TrackSession
    from tracker.sources.simulator import SimulatedTable

    src = SimulatedTable("static", seed=3, realtime=False, n_frames=frames)
    ts = TrackSession(src.parts, src.intrinsics, src.initial_poses,
                      TrackerConfig.preset("default").with_overrides(**overrides), seed=0)
    skipped, held, t_err = [], [], []
    for i in range(frames):
        frame = src.render(i)
        state, _ = ts.step(frame)
        skipped.append(ts.tracker._quiet_now.copy())
        held.append(ts.tracker._settled.copy())
        truth = frame.meta["groundtruth"]["poses"]
        t_err.append(max(float(np.linalg.norm(state.poses[n].t - truth[n].t)) for n in state.poses))
    return np.array(skipped), np.array(held), np.array(t_err)


def test_quiet_skip_held_skips_the_pass_of_a_held_part_next_frame_too():
    """quiet_skip_held: a part held one frame (not refined) skips its pass the next frame as well, where it is
    refined; without it a held part's pass runs on that frame (it has no fresh correction to be quiet on)."""
    skip_on, held_on, t_on = _skips({**HELD, "quiet_skip_held": True})
    skip_off, held_off, t_off = _skips({**HELD, "quiet_skip_held": False})
    assert held_off.any() and held_on.any()
    # off: a pass is skipped only on the frames the part is held, never on the frame after (where it is refined)
    assert not (skip_off & ~held_off).any()
    # on: the frame after a held one skips the pass too while the part is refined; never held two frames in a row
    after = held_on[:-1] & skip_on[1:] & ~held_on[1:]
    assert after.sum() >= 5
    assert not (held_on[1:] & held_on[:-1]).any()
    assert skip_on.sum() > skip_off.sum()
    # at most quiet_max_skips (3) passes in a row
    run = np.zeros(skip_on.shape[1], int)
    for row in skip_on:
        run = np.where(row, run + 1, 0)
        assert run.max() <= 3
    assert t_on[5:].max() < 0.004
    assert np.median(t_on[5:]) <= np.median(t_off[5:]) + 0.0005


def _converged_run(rot: float, trans: float, frames: int = 14):
    """The ``static`` scene tracked with ``quiet_converged_rotation`` / ``_translation`` = ``rot`` / ``trans``
    (nothing else quiet on): per frame the quiet parts (``_settled``), each part's Gauss-Newton updates and poses."""
    from app.commands.track import TrackSession
    from tracker.sources.simulator import SimulatedTable

    src = SimulatedTable("static", seed=3, realtime=False, n_frames=frames)
    cfg = TrackerConfig.preset("default").with_overrides(quiet_converged_rotation=rot,
                                                         quiet_converged_translation=trans)
    ts = TrackSession(src.parts, src.intrinsics, src.initial_poses, cfg, seed=0)
    settled, updates, poses, t_err = [], [], [], []
    for i in range(frames):
        frame = src.render(i)
        state, _ = ts.step(frame)
        trk = ts.tracker
        settled.append(trk._settled.copy())
        updates.append([-1 if r is None else r.n_updates for r in trk._refiner.last])
        poses.append({n: (p.R.copy(), p.t.copy()) for n, p in state.poses.items()})
        truth = frame.meta["groundtruth"]["poses"]
        t_err.append(max(float(np.linalg.norm(state.poses[n].t - truth[n].t)) for n in state.poses))
    return np.array(settled), np.array(updates), poses, np.array(t_err)


def test_quiet_converged_ends_a_quiet_parts_updates_early():
    """quiet_converged_rotation / _translation: the quiet parts of a resting scene stop their Gauss-Newton updates
    once converged (fewer than the 4 thresholds x 2 updates), the parts that are not quiet run them all, and the poses
    stay as precise; a bound no update meets leaves every pose as the setting off does (the quiet tests alone do
    not change a pose)."""
    settled, updates, _, t_err = _converged_run(0.001745, 5e-5)
    assert settled.sum() >= 10
    full = 8  # refine_thresholds x refine_updates of the default preset
    quiet_updates = updates[settled]
    assert quiet_updates.min() >= 1
    assert np.mean(quiet_updates) < full - 1.5  # most quiet refinements end early
    others = updates[~settled & (updates >= 0)]
    assert others.size and np.all(others <= full)
    assert t_err[5:].max() < 0.004
    # off, and on with a bound no update can meet: the same poses on every frame
    _, _, poses_off, _ = _converged_run(0.0, 0.0, frames=8)
    settled_tiny, _, poses_tiny, _ = _converged_run(1e-300, 1e-300, frames=8)
    assert settled_tiny.any()
    for a, b in zip(poses_off, poses_tiny, strict=True):
        for n in a:
            assert np.array_equal(a[n][0], b[n][0]) and np.array_equal(a[n][1], b[n][1])
    cfg = TrackerConfig.preset("default")
    assert cfg.quiet_converged_rotation == 0.0 and cfg.quiet_converged_translation == 0.0
