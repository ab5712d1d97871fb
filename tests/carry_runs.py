"""Shared simulated runs of the hand-carry tests (tuning seeds only), each computed once per test process."""

from __future__ import annotations

from functools import cache

import numpy as np

SNATCH_FRAMES = np.arange(200, 266)
"""Frames of :func:`snatch_under_arm`: the hand takes the cube at frame 247."""


@cache
def snatch_under_arm(hands: bool = False, take_m: float = 0.0,
                     left_table: float = 0.0, tracker_seed: int = 5) -> tuple[np.ndarray, frozenset[str] | None]:
    """Simulated guess-2 (tuning seed 0), frames 200-265 (``SNATCH_FRAMES``), tracked as ``track`` does
    (:class:`app.commands.track.TrackSession`, default preset, ``carry_shadow_take_m`` = ``take_m``,
    ``carry_left_table`` = ``left_table`` — on by default since session 18, off here unless given, so that the
    other ways of taking the cube are measured alone — the hand tracker with ``hands``) from the true poses at frame
    200: the yellow cube rests hidden under a hand (2 % visible), which takes it at frame 247 and carries it 7 cm while
    the arm keeps most of its place covered. Returns yellow's translation error (m) per frame and the parts the hands
    touched last (None without hands)."""
    from app.commands.track import TrackSession
    from tracker.filter.tracker_config import TrackerConfig
    from tracker.sources.simulator import SimulatedTable

    src = SimulatedTable("guess-2", seed=0, realtime=False, n_frames=int(SNATCH_FRAMES[-1]) + 1)
    cfg = TrackerConfig.preset("default").with_overrides(carry_shadow_take_m=take_m, carry_left_table=left_table)
    session, errs = None, []
    for i in SNATCH_FRAMES:
        frame = src.render(int(i))
        truth = frame.meta["groundtruth"]["poses"]
        if session is None:
            session = TrackSession(src.parts, src.intrinsics, truth, cfg, seed=tracker_seed, hands=hands)
        state, _ = session.step(frame)
        errs.append(state.poses["yellow"].translation_error(truth["yellow"]))
    touched = session.hands.touched_parts() if session.hands is not None else None
    errors = np.array(errs)
    errors.flags.writeable = False  # shared between tests (cached)
    return errors, None if touched is None else frozenset(touched)
