"""``carry_patch_radius`` (filter/hand_carry.py): the hand patch a carry registers from frame to frame."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

from tracker.filter.hand_carry import HandCarry
from tracker.filter.tracker_config import TrackerConfig

FRAMES = range(74, 109)
"""Frames of :func:`_hidden_carry`: the hand holds the red cube hidden (0-5 % of it in view) and carries it about
8 cm, then holds it still."""


@cache
def _hidden_carry(patch_radius: float, projective: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Simulated guess-1, fixed camera, occlusion 1.5, speed 2 (tuning seed 2; as recorded: whole millimetres), the
    hand carry alone (:class:`HandCarry`, default preset with ``carry_patch_radius`` = ``patch_radius`` and
    ``carry_projective`` = ``projective``) started at
    the red cube's true position at frame 74 and moved by the hand's registration only, each frame. Returns the
    carried position's error (m, camera frame, per frame from frame 75) and its component along the viewing ray (m,
    + = away from the camera)."""
    from benchmarks.bench_heldout import as_recorded
    from tracker.sources.simulator import SimOptions, SimulatedTable

    src = SimulatedTable("guess-1", seed=2, realtime=False, n_frames=FRAMES[-1] + 1,
                         options=SimOptions(speed=2.0, occlusion=1.5, camera_motion="none"))
    cfg = TrackerConfig.preset("default").with_overrides(carry_patch_radius=patch_radius,
                                                         carry_projective=projective)
    names = [p.name for p in src.parts]
    red = names.index("red")
    carry = HandCarry(len(names), cfg, src.intrinsics, np.full(len(names), 0.031))
    hidden = np.array([n == "red" for n in names])
    heights = np.where(hidden, 0.05, 0.0)  # red in the air: the carry starts at once
    pos, errors = None, []
    for i in FRAMES:
        frame = src.render(i)
        depth = as_recorded(frame.depth)
        truth = np.array([frame.meta["groundtruth"]["poses"][n].t for n in names])
        if pos is None:
            pos = truth.copy()
        rot, delta = carry.update(depth, pos, hidden, ~hidden, heights, src.table_plane)
        pos[red] = rot[red] @ pos[red] + delta[red]
        if i > FRAMES[0]:
            errors.append(pos[red] - truth[red])
        assert carry.carried[red]
    errors = np.array(errors)
    ray = frame.meta["groundtruth"]["poses"]["red"].t
    return np.linalg.norm(errors, axis=1), errors @ (ray / np.linalg.norm(ray))


@pytest.mark.slow
def test_a_larger_hand_patch_keeps_a_hidden_carry_from_drifting_toward_the_camera():
    """carry_radius's 8 cm sphere around the hidden cube, which sits behind the hand's visible surface, cuts a small
    cap of the hand: registered frame to frame it carries the cube toward the camera (traced in the benchmark's
    guess-1 fixed-camera session: 0.45 mm a frame). A 10 cm patch halves that drift along the ray; with 0 (or
    carry_radius) the carry is the default's."""
    base, base_ray = _hidden_carry(0.0)
    same, _ = _hidden_carry(0.08)
    wide, wide_ray = _hidden_carry(0.10)
    assert np.array_equal(base, same)  # not above carry_radius: the patch as before
    assert base_ray[-1] < -0.006, base_ray[-1]  # the default's drift toward the camera (7.2 mm in 34 frames)
    assert abs(wide_ray[-1]) < 0.6 * abs(base_ray[-1]), (wide_ray[-1], base_ray[-1])  # 3.3 mm
    # not a cure: the wide patch's error across the ray grows, its distance to the truth stays about the same
    assert wide[-1] < base[-1] + 0.002, (wide[-1], base[-1])


@pytest.mark.slow
def test_the_projective_refinement_keeps_a_hidden_carry_with_the_hand():
    """The same hidden carry with ``carry_projective`` (10 rounds): each frame's nearest-neighbour registration of the
    hand patch finished by projective pairing against the depth image. While the hand holds the cube (frames 75-104;
    it lets go from frame 105) the default drifts toward the camera (5.8 mm by frame 104, 3.4 mm from the truth on
    average, 6.1 at most), with it 2.3, 1.2 and 2.8 mm; 0 is the default bit for bit."""
    base, base_ray = _hidden_carry(0.0)
    off, _ = _hidden_carry(0.0, 0)
    proj, proj_ray = _hidden_carry(0.0, 10)
    assert np.array_equal(base, off)
    held = slice(0, 30)  # frames 75-104
    assert base_ray[29] < -0.004, base_ray[29]
    assert abs(proj_ray[29]) < 0.5 * abs(base_ray[29]), (proj_ray[29], base_ray[29])
    assert proj[held].mean() < 0.5 * base[held].mean(), (proj[held].mean(), base[held].mean())
