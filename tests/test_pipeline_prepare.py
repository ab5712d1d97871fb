"""Colour detection ahead of a frame's turn (``AssemblyPipeline.prepare``, run by the server's frame reader): the
snapshots are the same as without it, and a prepared result that no longer fits (another frame, a replaced detector)
is not used."""

from __future__ import annotations

import numpy as np
import pytest
from test_worker import SyntheticTable, make_pipeline, wait_for

from app.worker import PipelineWorker
from tracker.filter.tracker_config import TrackerConfig
from tracker.perception.color_detection import ColorDetector
from tracker.pipeline import AssemblyPipeline
from tracker.sources.simulator import SimulatedTable

CONFIG = TrackerConfig.preset("default").with_overrides(n_particles=30)


@pytest.fixture(scope="module")
def table_frames():
    src = SimulatedTable("static", seed=3, realtime=False, n_frames=6)
    return src.parts, src.intrinsics, src.initial_poses, list(src)


def _pipeline(table_frames) -> AssemblyPipeline:
    parts, intr, poses, _ = table_frames
    return AssemblyPipeline(parts, intr, mode="guidance", task="guidance-5-cubes", config=CONFIG, seed=2,
                            initial_poses=poses)


def _same_snapshots(a, b) -> None:
    assert a.poses.keys() == b.poses.keys()
    for n in a.poses:
        assert np.array_equal(a.poses[n].t, b.poses[n].t) and np.array_equal(a.poses[n].q, b.poses[n].q)
    assert a.particles.keys() == b.particles.keys()
    for n in a.particles:
        assert np.array_equal(a.particles[n], b.particles[n])
    assert a.detections == b.detections and a.boxes == b.boxes
    assert a.mode_state == b.mode_state and a.errors == b.errors


def test_prepared_detections_give_the_same_snapshots(table_frames):
    frames = table_frames[3]
    here, ahead = _pipeline(table_frames), _pipeline(table_frames)
    for frame in frames:
        plain = here.process(frame)
        prepared = ahead.prepare(frame)
        assert prepared is not None and prepared.frame is frame and prepared.cpu_s >= 0.0
        snap = ahead.process(frame, prepared=prepared)
        _same_snapshots(plain, snap)
        assert "detection_ahead" in snap.timings and "detection_ahead" not in plain.timings
        assert any(d["center"] is not None for d in snap.detections.values())


def test_prepared_detections_that_no_longer_fit_are_not_used(table_frames):
    frames = table_frames[3]
    p = _pipeline(table_frames)
    calls = []
    det = p.detector
    detect = det.detect
    det.detect = lambda rgb: calls.append(1) or detect(rgb)
    other = p.prepare(frames[1])  # made for another frame
    assert len(calls) == 1
    snap = p.process(frames[0], prepared=other)
    assert len(calls) == 2 and "detection_ahead" not in snap.timings  # detected again
    p.process(frames[1])
    prepared = p.prepare(frames[2])
    assert len(calls) == 4
    p.detector = ColorDetector(dict(det.ranges))  # replaced (a calibration): the prepared detections are stale
    snap = p.process(frames[2], prepared=prepared)
    assert len(calls) == 4 and "detection_ahead" not in snap.timings  # the new detector detected
    fresh = _pipeline(table_frames)
    for frame in frames[:3]:
        ref = fresh.process(frame)
    assert snap.detections == ref.detections
    _same_snapshots(snap, ref)


def test_worker_prepares_ahead_with_the_same_results():
    last = {}
    for ahead in (False, True):
        worker = PipelineWorker(lambda: SyntheticTable(n_frames=12), make_pipeline, max_fps=None, loop=False,
                                prepare_ahead=ahead)
        snaps = []
        worker.add_listener(snaps.append)
        worker.start()
        try:
            assert wait_for(lambda w=worker: w.state == "finished")
        finally:
            worker.stop()
        assert [s.frame_index for s in snaps] == list(range(12))
        assert all(("detection_ahead" in s.timings) == ahead for s in snaps)
        last[ahead] = snaps[-1]
    _same_snapshots(last[False], last[True])


def test_prepare_stages_the_frame_for_the_hand_process(table_frames):
    """With hands on (the hand step in its process), ``prepare`` also copies the frame into the hand process's shared
    memory (:meth:`HandLoop.stage`) and the step sends that copy: the snapshots, hands included, are those of a
    pipeline without ``prepare``, and every frame after the first (the process starts with it) was staged and taken."""
    from tracker.hands.loop import HandLoopConfig

    parts, intr, poses, frames = table_frames
    cfg = HandLoopConfig(step_timeout_s=600.0)

    def pipeline() -> AssemblyPipeline:
        return AssemblyPipeline(parts, intr, mode="guidance", task="guidance-5-cubes", config=CONFIG, seed=2,
                                initial_poses=poses, hands=True, hand_config=cfg)  # fmt: skip

    here, ahead = pipeline(), pipeline()
    staged = 0
    try:
        for frame in frames:
            plain = here.process(frame)
            prepared = ahead.prepare(frame)
            proc = ahead.hands._process
            if proc is not None:
                assert len(proc._staged) == 1
                staged += 1
            snap = ahead.process(frame, prepared=prepared)
            assert proc is None or not proc._staged  # taken by the step
            _same_snapshots(plain, snap)
            assert snap.hands == plain.hands
        assert staged == len(frames) - 1
    finally:
        here.close()
        ahead.close()
