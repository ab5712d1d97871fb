"""Worker in real time: paced sources skip stale frames, capture times are the frames' due times; table re-check.

Deterministic in what is asserted: the pipeline is made slower than the source on purpose, so frames
must be skipped whatever the machine's load; time bounds are generous.
"""

from __future__ import annotations

import threading
import time

import numpy as np
from test_worker import TABLE_NORMAL, SyntheticTable, make_pipeline, wait_for

from app.worker import AHEAD_MAX_S, PipelineWorker, _FramePrefetcher, _RandomAccess
from tracker.frame import Frame
from tracker.pipeline import AssemblyPipeline


class RenderedTable(SyntheticTable):
    """The synthetic table with the simulator's random access: ``render(i)``, ``n_frames``, ``metadata()["fps"]``."""

    def __init__(self, fps: float = 100.0, **kw):
        super().__init__(**kw)
        self.fps = fps
        self.rendered: list[int] = []

    def metadata(self):
        return {**super().metadata(), "fps": self.fps}

    def render(self, index: int) -> Frame:
        self.rendered.append(index)
        return Frame(index, index / self.fps, self.color.copy(), self.depth.copy(), self.intrinsics)

    def __iter__(self):
        raise AssertionError("a paced source is read by index, not iterated")


class SlowPipeline:
    """A pipeline that takes at least ``delay`` seconds per frame (slower than the source)."""

    def __init__(self, src, delay: float = 0.06):
        self.inner = make_pipeline(src)
        self.parts = self.inner.parts
        self.delay = delay

    def process(self, frame, wall_time=None):
        threading.Event().wait(self.delay)
        return self.inner.process(frame, wall_time)


def test_random_access_of_sources():
    src = RenderedTable(fps=50.0, n_frames=20)
    acc = _RandomAccess.of(src)
    assert acc is not None and acc.count == 20
    assert acc.due(0.0) == 0 and acc.due(0.019) == 0 and acc.due(0.021) == 1 and acc.due(0.1) == 5
    assert acc.offset(5) == 5 / 50.0
    assert _RandomAccess.of(SyntheticTable()) is None  # only iterable: read on demand


def test_realtime_drops_stale_frames_and_reports_capture_times():
    """A 100 fps source and a pipeline taking ≥ 60 ms: each processed frame is the newest due one."""
    src = RenderedTable(fps=100.0, n_frames=100_000)
    snaps = []
    worker = PipelineWorker(lambda: src, SlowPipeline, max_fps=None, realtime=True)
    worker.add_listener(snaps.append)
    worker.start()
    try:
        assert wait_for(lambda: len(snaps) >= 6)
    finally:
        worker.stop()
    idx = [s.frame_index for s in snaps]
    assert idx == sorted(set(idx))
    gaps = np.diff(idx)
    assert gaps[1:].min() >= 2, idx  # ≥ 60 ms per frame at 10 ms per source frame: stale frames skipped
    assert worker.frames_dropped >= int(gaps.sum()) - len(gaps)  # what was skipped is counted
    assert src.rendered[: len(idx)] == idx  # skipped frames were never rendered
    # capture time = the frame's due time: spaced exactly by the frame interval
    for a, b in zip(snaps, snaps[1:], strict=False):
        assert abs((b.wall_time - a.wall_time) - (b.frame_index - a.frame_index) / 100.0) < 1e-6
    # and the frame was processed after it was due, within a generous bound (no pile-up)
    for s in snaps:
        assert 0.0 <= s.timings["wait"] < 5.0


def test_unpaced_source_loses_no_frame():
    """Without real time (or for a source that can only be iterated) every frame is processed, in order."""
    seen = []
    worker = PipelineWorker(
        lambda: SyntheticTable(n_frames=12), lambda s: SlowPipeline(s, 0.01), max_fps=None, loop=False, realtime=True
    )
    worker.add_listener(lambda s: seen.append(s.frame_index))
    worker.start()
    try:
        assert wait_for(lambda: worker.state == "finished")
    finally:
        worker.stop()
    assert seen == list(range(12)) and worker.frames_dropped == 0


def test_table_is_rechecked_cheaply_and_redetected_when_it_moves(monkeypatch):
    import tracker.perception.table_plane as tp

    calls = []
    real = tp.detect_table

    def counting(depth, intrinsics, settings=None):
        calls.append(1)
        return real(depth, intrinsics, settings)

    monkeypatch.setattr(tp, "detect_table", counting)
    src = SyntheticTable(n_frames=1)
    p = AssemblyPipeline(src.parts, src.intrinsics, mode=None, config=make_pipeline(src).config, table_recheck_s=0.1)
    frame = next(iter(src))

    def at(t, depth):
        return Frame(int(t * 30), t, frame.color, depth, frame.intrinsics)

    first = p.process(at(0.0, frame.depth))
    assert len(calls) == 1 and first.table is not None
    for t in (0.2, 0.4, 0.6):  # re-checked (recheck every 0.1 s) but the plane still fits: no new detection
        p.process(at(t, frame.depth))
    assert len(calls) == 1
    # the camera moved: the table is now 10 cm further away along the viewing rays
    moved = (frame.depth * 1.15).astype(np.float32)
    snap = p.process(at(0.8, moved))
    assert len(calls) == 2
    assert abs(snap.table["offset"] - first.table["offset"]) > 0.03
    assert np.allclose(np.abs(snap.table["normal"]), np.abs(TABLE_NORMAL), atol=0.05)


class SlowRenderTable(RenderedTable):
    """A paced source whose frames take ``render_s`` seconds to produce; records when each production started."""

    def __init__(self, render_s: float, **kw):
        super().__init__(**kw)
        self.render_s = render_s
        self.started: dict[int, float] = {}

    def render(self, index: int) -> Frame:
        self.started[index] = time.time()
        threading.Event().wait(self.render_s)
        return super().render(index)


def _paced_items(ahead: bool, n: int = 8) -> tuple[SlowRenderTable, list[tuple]]:
    """``n`` frames of a 100 fps source taking 50 ms a frame, read by a paced prefetcher as the worker does."""
    src = SlowRenderTable(0.05, fps=100.0, n_frames=100_000)
    reader = _FramePrefetcher(src, realtime=True, ahead=ahead)
    items = []
    try:
        while len(items) < n:
            item = reader.get(timeout=5.0)
            assert item is not None and item[0] == "frame"
            items.append(item)
    finally:
        reader.close()
    return src, items


def test_realtime_ahead_produces_frames_before_they_are_due_and_hands_them_over_when_due():
    """With ``ahead`` the reader takes the frame due when its production ends (production ≥ 50 ms here, so every
    frame after the first is due at least 40 ms after its production started) and hands it over no earlier than its
    due time; without it every frame's production starts once the frame is due. Capture time = due time in both."""
    src, items = _paced_items(ahead=True)
    for _, frame, took, captured, ready, _ in items[1:]:
        assert captured - src.started[frame.index] >= 0.02  # produced ahead of its due time (≥ 40 ms less slack)
        assert ready >= captured - 1e-3 and took >= 0.05  # handed over when due, not before
    src, items = _paced_items(ahead=False)
    for _, frame, _, captured, ready, _ in items:
        assert src.started[frame.index] >= captured - 1e-3  # produced once due
        assert ready >= captured + 0.05 - 1e-3
    indices = [it[1].index for it in items]
    assert indices == sorted(set(indices))


def test_realtime_ahead_chooses_frames_at_most_a_capped_time_ahead():
    """A first production of 0.4 s (kernels compiling) does not make the reader choose, and hold, a frame due 0.4 s
    later: every frame is due at most ``AHEAD_MAX_S`` after its production started."""
    src = SlowRenderTable(0.005, fps=100.0, n_frames=100_000)
    slow = {"left": 2}
    render = src.render

    def first_slow(index):
        if slow["left"]:
            slow["left"] -= 1
            threading.Event().wait(0.4)
        return render(index)

    src.render = first_slow
    reader = _FramePrefetcher(src, realtime=True, ahead=True)
    try:
        items = [reader.get(timeout=5.0) for _ in range(6)]
    finally:
        reader.close()
    for _, frame, _, captured, _, _ in items:
        assert captured - src.started[frame.index] <= AHEAD_MAX_S + 1e-3


def test_worker_passes_realtime_ahead_to_its_reader():
    src = RenderedTable(fps=100.0, n_frames=100_000)
    snaps = []
    worker = PipelineWorker(lambda: src, lambda s: SlowPipeline(s, 0.01), max_fps=None, realtime=True,
                            realtime_ahead=True)  # fmt: skip
    worker.add_listener(snaps.append)
    worker.start()
    try:
        assert wait_for(lambda: len(snaps) >= 3)
        assert worker._reader is not None and worker._reader.ahead
    finally:
        worker.stop()
    idx = [s.frame_index for s in snaps]
    assert idx == sorted(set(idx))
