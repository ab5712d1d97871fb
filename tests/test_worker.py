"""Pipeline worker: runs frames in a thread, keeps the latest snapshot, survives failing frames and sources.

``SyntheticTable`` (a test double, also used by the API tests) renders a tilted table plane with
coloured squares; it can be told to raise on chosen frames or to die.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from app.worker import PipelineWorker
from tracker.frame import Frame
from tracker.geometry.camera import Intrinsics
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose
from tracker.perception.box_tools import guess_part, pose_from_rect
from tracker.pipeline import AssemblyPipeline
from tracker.sources.base import FrameSource

TABLE_NORMAL = np.array([0.0, -0.8, -0.6])  # up, towards the camera
TABLE_OFFSET = 0.48  # n·p + d = 0 through (0, 0, 0.8)


class SyntheticTable(FrameSource):
    """A tilted table with a red and a green square; ``fail_on`` frame indices raise, ``die_at`` ends the source."""

    name = "synthetic"

    def __init__(self, n_frames: int = 1000, fail_on: tuple[int, ...] = (), die_at: int | None = None, scale=0.25):
        self._intr = Intrinsics.default().scaled(scale)
        self.n_frames = n_frames
        self.fail_on = set(fail_on)
        self.die_at = die_at
        self.parts = [PartSpec.cube("red", "red"), PartSpec.cube("green", "green")]
        self.closed = False
        w, h = self._intr.width, self._intr.height
        v, u = np.mgrid[0:h, 0:w].astype(np.float64)
        ray_y = (v - self._intr.cy) / self._intr.fy
        self.depth = (TABLE_OFFSET / (0.8 * ray_y + 0.6)).astype(np.float32)
        self.color = np.full((h, w, 3), 150, np.uint8)
        self.color[h // 2 : h // 2 + 10, w // 4 : w // 4 + 10] = (210, 30, 35)
        self.color[h // 2 : h // 2 + 10, w // 2 : w // 2 + 10] = (40, 170, 60)
        self.initial_poses = {
            "red": self._on_table(w // 4 + 5, h // 2 + 5),
            "green": self._on_table(w // 2 + 5, h // 2 + 5),
        }

    def _on_table(self, u: float, v: float) -> Pose:
        z = float(self.depth[int(v), int(u)])
        p = self._intr.backproject(u, v, z) + TABLE_NORMAL * 0.018
        return Pose(p, np.array([0.0, 0.0, 0.0, 1.0]))

    @property
    def intrinsics(self) -> Intrinsics:
        return self._intr

    def __iter__(self):
        return self._frames()

    def _frames(self):
        for i in range(self.n_frames):
            if self.die_at is not None and i >= self.die_at:
                raise OSError("device unplugged")
            if i in self.fail_on:
                raise ValueError(f"corrupt frame {i}")
            yield Frame(i, i / 30.0, self.color.copy(), self.depth.copy(), self._intr)

    def close(self) -> None:
        self.closed = True


class StatefulFailing(FrameSource):
    """An iterator object (not a generator) that raises on some frames but keeps going."""

    name = "flaky"

    def __init__(self, fail_on=(2, 3)):
        self.inner = SyntheticTable()
        self.parts = self.inner.parts
        self.initial_poses = self.inner.initial_poses
        self.fail_on = set(fail_on)
        self.i = 0

    @property
    def intrinsics(self):
        return self.inner.intrinsics

    def __iter__(self):
        return self

    def __next__(self):
        i = self.i
        self.i += 1
        if i in self.fail_on:
            raise ValueError(f"corrupt frame {i}")
        return Frame(i, i / 30.0, self.inner.color.copy(), self.inner.depth.copy(), self.inner.intrinsics)


def make_pipeline(src) -> AssemblyPipeline:
    from tracker.filter.tracker_config import TrackerConfig

    config = TrackerConfig.preset("default").with_overrides(n_particles=20)
    return AssemblyPipeline(src.parts, src.intrinsics, mode=None, config=config, initial_poses=src.initial_poses)


def wait_for(cond, timeout=20.0):
    t0 = time.time()
    while time.time() - t0 < timeout:
        if cond():
            return True
        time.sleep(0.02)
    return False


def test_worker_processes_frames_and_keeps_latest():
    worker = PipelineWorker(lambda: SyntheticTable(n_frames=30), make_pipeline, max_fps=None, loop=False)
    seen = []
    worker.add_listener(lambda s: seen.append(s.frame_index))
    worker.start()
    try:
        assert wait_for(lambda: worker.state == "finished")
    finally:
        worker.stop()
    assert worker.frames_processed == 30
    assert seen == list(range(30))
    assert worker.latest.frame_index == 29
    assert set(worker.latest.poses) == {"red", "green"}
    assert worker.latest.table is not None  # the table plane was found
    idx, jpeg = worker.jpeg()
    assert idx == 29 and jpeg[:2] == b"\xff\xd8"


def test_corrupt_frame_is_skipped_and_reported():
    worker = PipelineWorker(lambda: StatefulFailing(fail_on=(2, 3)), make_pipeline, max_fps=None)
    worker.start()
    try:
        assert wait_for(lambda: worker.frames_processed >= 8)
    finally:
        worker.stop()
    messages = [e.message for e in worker.errors]
    assert any("corrupt frame 2" in m for m in messages)
    assert any("corrupt frame 3" in m for m in messages)
    assert worker.frames_skipped == 2
    assert worker.source_opens == 1  # the same source went on after the bad frames


def test_dying_source_is_reported_and_reopened():
    opened = []

    def open_source():
        src = SyntheticTable(die_at=5)
        opened.append(src)
        return src

    worker = PipelineWorker(open_source, make_pipeline, max_fps=None, reopen_delay_s=0.01)
    worker.start()
    try:
        assert wait_for(lambda: worker.source_opens >= 3)
    finally:
        worker.stop()
    assert any("device unplugged" in e.message for e in worker.errors)
    assert any("reopening" in e.message for e in worker.errors)
    assert opened[0].closed
    assert worker.frames_processed >= 10


def test_source_that_cannot_open_is_retried():
    attempts = []

    def open_source():
        attempts.append(1)
        if len(attempts) < 3:
            raise OSError("camera 0 busy")
        return SyntheticTable(n_frames=3)

    worker = PipelineWorker(open_source, make_pipeline, max_fps=None, loop=False, reopen_delay_s=0.01)
    worker.start()
    try:
        assert wait_for(lambda: worker.state == "finished")
    finally:
        worker.stop()
    assert sum(1 for e in worker.errors if "camera 0 busy" in e.message) == 2
    assert worker.frames_processed == 3


def test_pause_and_commands_run_on_worker_thread():
    worker = PipelineWorker(lambda: SyntheticTable(), make_pipeline, max_fps=200)
    worker.start()
    try:
        assert wait_for(lambda: worker.frames_processed >= 3)
        worker.pause()
        assert wait_for(lambda: worker.state == "paused")
        n = worker.frames_processed
        time.sleep(0.2)
        assert worker.frames_processed == n
        import threading

        result = worker.submit(lambda p, f: (threading.current_thread().name, f.index)).result(timeout=5)
        assert result[0] == "pipeline-worker"
        with pytest.raises(ValueError, match="unknown part"):
            worker.submit(lambda p, f: p.part("nope")).result(timeout=5)
        worker.start()
        assert wait_for(lambda: worker.frames_processed > n)
    finally:
        worker.stop()


def test_parts_without_pose_start_tracking_when_a_box_is_drawn():
    """Like a live camera: no initial poses; drawing a box over a part starts tracking just that part."""
    src = SyntheticTable(n_frames=4)
    from tracker.filter.tracker_config import TrackerConfig

    config = TrackerConfig.preset("default").with_overrides(n_particles=20)
    p = AssemblyPipeline(src.parts, src.intrinsics, mode=None, config=config, initial_poses=None)
    frames = list(src)
    snap = p.process(frames[0])
    assert snap.poses == {} and p.tracker is None
    assert snap.table is not None
    w = src.intrinsics.width
    h = src.intrinsics.height
    rect = (w // 4 - 2, h // 2 - 2, 14, 14)  # around the red square
    name = guess_part(p.parts, p.detector, frames[0].color, rect)
    assert name == "red"
    pose = pose_from_rect(p.part(name), rect, p.intrinsics, p.table, frames[0].depth)
    # the cube's centre is half an edge above the table plane
    height = float(TABLE_NORMAL @ pose.t + TABLE_OFFSET)
    assert abs(height - 0.018) < 0.004
    p.set_part_pose(name, pose)
    snap = p.process(frames[1])
    assert set(snap.poses) == {"red"} and set(snap.particles) == {"red"}
    assert not snap.errors


def test_live_source_busy_pipeline_gets_newest_frame():
    """With drop_stale (live cameras) frames that arrive while the pipeline is busy are skipped, not queued."""

    class SlowPipeline:
        def __init__(self, src):
            self.inner = make_pipeline(src)
            self.parts = self.inner.parts

        def process(self, frame, wall_time=None):
            time.sleep(0.05)
            return self.inner.process(frame, wall_time)

    seen = []
    worker = PipelineWorker(lambda: SyntheticTable(n_frames=100_000), SlowPipeline, max_fps=None, drop_stale=True)
    worker.add_listener(lambda s: seen.append(s.frame_index))
    worker.start()
    try:
        assert wait_for(lambda: len(seen) >= 6)
    finally:
        worker.stop()
    assert worker.frames_dropped > 0
    assert seen == sorted(seen) and seen[-1] - seen[0] > len(seen)  # gaps: stale frames were skipped


def test_a_replaced_pipeline_is_closed_keeping_its_hand_process_and_the_last_one_at_stop():
    """Each reopening (here: a source that ends, with ``loop``) replaces the pipeline: the old one is closed with
    ``keep_hand_process=True`` (its hand process serves the next pipeline of the same parts); when the worker stops,
    its pipeline is closed for good."""
    closed: list[tuple[int, bool]] = []

    class Closing:
        def __init__(self, src) -> None:
            self.inner = make_pipeline(src)
            self.number = len(built)
            built.append(self)

        def process(self, frame, wall_time=None):
            return self.inner.process(frame, wall_time=wall_time)

        def close(self, keep_hand_process: bool = False) -> None:
            closed.append((self.number, keep_hand_process))

    built: list[Closing] = []
    worker = PipelineWorker(lambda: SyntheticTable(n_frames=3), Closing, max_fps=None, loop=True)
    worker.start()
    try:
        assert wait_for(lambda: worker.source_opens >= 3)
    finally:
        worker.stop()
    assert not worker.errors
    n = len(built)
    assert closed == [(i, True) for i in range(n - 1)] + [(n - 1, False)]
