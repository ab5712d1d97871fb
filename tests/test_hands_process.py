"""The hand step in a child process (``HandLoopConfig.worker`` "process", :mod:`tracker.hands.process`): same results
as the step run in this process; bad frames, a dying process and closing."""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

from tracker.compile_reporter import CompileReporter
from tracker.geometry.camera import Intrinsics
from tracker.hands.loop import HandLoop, HandLoopConfig
from tracker.hands.process import HandProcess, HandProcessError, close_parked
from tracker.hands.tracker import HandTrackerConfig


def _entering_palm(k: int) -> np.ndarray:
    """Frame k of a skin-coloured 70×60 palm on a 24 px wide forearm, entering from the left image border at 7 px per
    frame over a grey table, drifting down 1 px per frame (0: no hand)."""
    img = np.zeros((480, 640, 3), np.uint8) + np.uint8([120, 130, 140])
    if k:
        x = -60 + 7 * k
        y = 200 + k
        img[y + 18 : y + 42, : max(x, 0)] = [205, 150, 120]  # the forearm, from the border
        img[y : y + 60, max(x, 0) : max(x + 70, 0)] = [215, 160, 130]
    return img


STEP_TIMEOUT = 600.0
"""Seconds a step of the child may take here: its first step loads the compiled kernels and fits the session
background, which took more than the default 20 s when the machine ran other jobs at a load of 25 on 2 cores (the
timeout would restart the child and the comparisons below would fail for the load, not for the code)."""


def _loop(worker: str, overlap: str = "wait") -> HandLoop:
    cfg = HandLoopConfig(tracker=HandTrackerConfig(seed=3), occluder_prior=True, overlap=overlap, worker=worker,
                         step_timeout_s=STEP_TIMEOUT)  # fmt: skip
    return HandLoop([], Intrinsics.default(), cfg)


@pytest.mark.parametrize("overlap", ["wait", "lagged"])
def test_process_step_equals_the_step_in_this_process(overlap):
    """A seeded sequence (automatic track start on a hand entering from the border): the child process gives the same
    estimates, hand masks and occluder masks (this frame's, and the one predicted to the next frame) as the step run
    in the caller's thread; the hand is found, so the comparison covers tracking, not only empty frames."""
    here, there = _loop("thread", "off"), _loop("process", overlap)
    try:
        with_hands = 0
        for k in range(16):
            frame = _entering_palm(k)
            here.start(frame, None, None, {})
            there.start(frame, None, None, {})
            there.wait()
            assert there.worker_pid is not None and there.worker_pid != os.getpid()
            assert [e.box for e in there.estimates] == [e.box for e in here.estimates]
            assert [e.id for e in there.estimates] == [e.id for e in here.estimates]
            for a, b in zip(there.estimates, here.estimates, strict=True):
                assert np.array_equal(a.state, b.state) and a.score == b.score
            assert there.masks.keys() == here.masks.keys()
            for tid, m in here.masks.items():
                assert np.array_equal(there.masks[tid], m)
            for mine, theirs in ((here.occluder, there.occluder), (here.next_occluder, there.next_occluder)):
                assert (mine is None) == (theirs is None)
                assert mine is None or np.array_equal(mine, theirs)
            assert there.step_seconds[1] > 0.0  # the child's thread CPU time of the step
            with_hands += bool(here.estimates)
        assert with_hands >= 5
        assert here.estimates and here.masks[here.estimates[0].id].any()
    finally:
        there.close()


def test_a_bad_frame_is_reported_and_the_process_goes_on():
    """A frame of the wrong size is refused before it reaches the child; a malformed table plane fails inside the
    child's step: both raise from wait with their own error types, and the next good frame is stepped by the same
    child."""
    loop = _loop("process")
    try:
        loop.start(_entering_palm(0), None, None, {})
        loop.wait()
        pid = loop.worker_pid
        loop.start(np.zeros((10, 10), np.uint8), None, None, {})
        with pytest.raises(ValueError, match="uint8 RGB image"):
            loop.wait()
        depth = np.full((480, 640), 0.7, np.float32)
        loop.start(_entering_palm(1), depth, ("not a plane",), {})
        with pytest.raises(Exception) as info:
            loop.wait()
        assert not isinstance(info.value, HandProcessError)  # the step's own error, the process lives
        loop.start(_entering_palm(2), None, None, {})
        loop.wait()
        assert loop.worker_pid == pid
    finally:
        loop.close()


def test_a_dying_hand_process_is_reported_and_restarted():
    """The child is killed mid-session: the next wait reports it (HandProcessError, the hands are cleared), a new
    child starts; once it is ready, it is given the session's first frame again (the skin model's session background,
    hand-free), then the current frames: hands are tracked again (automatic start) and the results equal those of a
    fresh in-thread loop given the first frame and then the same frames."""
    loop = _loop("process")
    try:
        for k in range(8):
            loop.start(_entering_palm(k), None, None, {})
            loop.wait()
        assert loop.estimates
        first = loop.worker_pid
        os.kill(first, signal.SIGKILL)
        loop._process._res.proc.join()
        loop.start(_entering_palm(8), None, None, {})
        with pytest.raises(HandProcessError, match="ended"):
            loop.wait()
        assert loop.estimates == [] and loop.masks == {}
        assert loop.worker_pid is not None and loop.worker_pid != first
        assert loop._process.restarts == 1
        assert loop._process.wait_ready(120.0)
        fresh = _loop("thread", "off")
        fresh.start(_entering_palm(0), None, None, {})
        for k in range(9, 25):
            loop.start(_entering_palm(k), None, None, {})
            fresh.start(_entering_palm(k), None, None, {})
            loop.wait()
            assert [e.box for e in loop.estimates] == [e.box for e in fresh.estimates]
        assert loop.estimates
    finally:
        loop.close()


def test_a_new_childs_first_step_is_given_the_start_time():
    """A new child's first step loads the compiled kernels (after an upgrade it compiles them: minutes on a busy
    machine), so it is given the start's time, not a step's: with a step timeout far below any step's time the first
    step still answers (before, every new child was ended mid-compile and the hands given up)."""
    close_parked()  # a parked child has stepped already
    cfg = HandLoopConfig(tracker=HandTrackerConfig(seed=3), occluder_prior=True, overlap="wait", worker="process",
                         step_timeout_s=1e-3)  # fmt: skip
    loop = HandLoop([], Intrinsics.default(), cfg)
    try:
        loop.start(_entering_palm(0), None, None, {})
        loop.wait()
        assert loop._process.restarts == 0 and loop._process._stepped  # later steps: the step's timeout
    finally:
        loop.close()


class _Pipe:
    """A stand-in for the parent's end of the pipe: ``poll`` answers from a script of messages and records the
    timeouts it was asked to wait."""

    def __init__(self, messages: list[tuple]) -> None:
        self.messages = list(messages)
        self.timeouts: list[float] = []
        self.sent: list = []

    def poll(self, timeout: float) -> bool:
        self.timeouts.append(timeout)
        return bool(self.messages)

    def recv(self) -> tuple:
        return self.messages.pop(0)

    def send(self, msg) -> None:
        self.sent.append(msg)


def test_a_step_during_which_the_child_compiles_is_given_the_start_time():
    """The child's first frame with a hand compiles the hand path's kernels after an upgrade (20 s of CPU; session 20's
    server run ended the child at the step timeout, again in every new child): each "compiling" message gives the rest
    of the step the start's time; without one the step's own timeout applies."""
    proc = HandProcess([], Intrinsics.default(), HandLoopConfig(), start_timeout=300.0, step_timeout=2.0)
    try:
        pipe = _Pipe([("compiling", "a"), ("compiling", "b"), ("done", {"estimates": []})])
        proc._res.conn, proc._pending, proc._stepped = pipe, True, True
        assert proc.result() == {"estimates": []}
        assert pipe.timeouts == [2.0, 300.0, 300.0] and proc.compiles == 2 and proc.restarts == 0
        pipe = _Pipe([("done", {"estimates": [1]})])
        proc._res.conn, proc._pending = pipe, True
        assert proc.result() == {"estimates": [1]} and pipe.timeouts == [2.0]
        # a new session's loop that compiles before it says it is ready
        pipe = _Pipe([("compiling", "c"), ("ready",)])
        proc._res.conn, proc._ready = pipe, False
        assert proc._check_ready(5.0)
    finally:
        proc._res.conn = None
        proc.close()


def test_the_child_reports_a_compile_but_not_a_cached_kernel():
    """The child's listener sends ("compiling", the kernel's name) when numba compiles (a cache miss), at most once a
    second; calling a compiled kernel again sends nothing."""
    import numba as nb
    from numba.core import event

    @nb.njit
    def _never_compiled_before(x):
        return x * 3 + 1

    pipe = _Pipe([])
    reporter = CompileReporter(pipe)
    event.register("numba:compile", reporter)
    try:
        assert _never_compiled_before(2) == 7
        assert pipe.sent == [("compiling", _never_compiled_before.py_func.__qualname__)]
        reporter._last = -float("inf")
        assert _never_compiled_before(3) == 10  # compiled for int64 already
        assert len(pipe.sent) == 1
        reporter._last = time.monotonic() + 1e3  # a message was just sent
        _never_compiled_before(2.5)  # a new signature compiles, within the second since the last message: no message
        assert len(pipe.sent) == 1
        reporter._last = -float("inf")
        _never_compiled_before(np.int8(1))
        assert len(pipe.sent) == 2
    finally:
        event.unregister("numba:compile", reporter)


def _same_hands(a: HandLoop, b: HandLoop) -> None:
    assert [e.box for e in a.estimates] == [e.box for e in b.estimates]
    assert [e.id for e in a.estimates] == [e.id for e in b.estimates]
    for x, y in zip(a.estimates, b.estimates, strict=True):
        assert np.array_equal(x.state, y.state) and x.score == y.score
    assert a.masks.keys() == b.masks.keys()
    for tid, m in a.masks.items():
        assert np.array_equal(b.masks[tid], m)
    assert (a.occluder is None) == (b.occluder is None)
    assert a.occluder is None or np.array_equal(a.occluder, b.occluder)


def test_a_kept_process_serves_the_next_loop_with_the_hands_of_a_new_one():
    """``close(keep_process=True)`` (the server's pipeline replaced when its source loops) parks the child mid-session
    (a hand tracked); the next loop of the same parts and configuration takes the same child, and its hands over a
    new session equal those of a fresh in-thread loop; a loop with another configuration does not take it (the
    parked child is ended) and starts its own."""
    first = _loop("process")
    second = other = None
    try:
        for k in range(10):
            first.start(_entering_palm(k), None, None, {})
            first.wait()
        assert first.estimates
        pid = first.worker_pid
        first.close(keep_process=True)
        assert first.worker_pid is None
        second, fresh = _loop("process"), _loop("thread", "off")
        with_hands = 0
        for k in range(14):
            frame = _entering_palm(k)
            second.start(frame, None, None, {})
            fresh.start(frame, None, None, {})
            second.wait()
            assert second.worker_pid == pid
            _same_hands(fresh, second)
            with_hands += bool(fresh.estimates)
        assert with_hands >= 4
        kept = second._process._res.proc
        second.close(keep_process=True)
        assert kept.is_alive()
        other = HandLoop([], Intrinsics.default(), HandLoopConfig(tracker=HandTrackerConfig(seed=4),
                                                                   step_timeout_s=STEP_TIMEOUT))  # fmt: skip
        other.start(_entering_palm(0), None, None, {})
        other.wait()
        assert other.worker_pid not in (None, pid)
        kept.join(15.0)
        assert not kept.is_alive()
    finally:
        for loop in (first, second, other):
            if loop is not None:
                loop.close()
        close_parked()


def test_close_ends_the_child_and_frees_the_shared_memory():
    from multiprocessing.shared_memory import SharedMemory

    loop = _loop("process")
    loop.start(_entering_palm(0), None, None, {})
    loop.wait()
    proc = loop._process._res.proc
    name = loop._process._res.shm.name
    loop.close()
    assert not proc.is_alive() and proc.exitcode is not None  # asked to stop (killed if it does not in time)
    with pytest.raises(FileNotFoundError):
        SharedMemory(name=name)
    loop.close()  # twice is harmless


def test_pipeline_reports_a_dead_hand_process_and_keeps_running():
    """In the pipeline (the server's worker calls it per frame) a killed hand process costs one frame's hands: that
    snapshot carries the error, the cube tracker's poses are still there, and after the new child is ready the
    snapshots come without errors."""
    from tracker.pipeline import AssemblyPipeline
    from tracker.sources.simulator import SimulatedTable

    src = SimulatedTable("guidance-demo", seed=100, realtime=False)
    pipe = AssemblyPipeline(src.parts, src.intrinsics, mode="guidance", initial_poses=src.initial_poses, hands=True,
                            hand_config=HandLoopConfig(step_timeout_s=STEP_TIMEOUT))  # fmt: skip
    try:
        for i in range(3):
            assert not pipe.process(src.render(i)).errors
        os.kill(pipe.hands.worker_pid, signal.SIGKILL)
        pipe.hands._process._res.proc.join()
        snap = pipe.process(src.render(3))
        assert any(e.startswith("hands: HandProcessError") for e in snap.errors)
        assert set(snap.poses) == {p.name for p in src.parts}
        assert pipe.hands._process.wait_ready(120.0)
        for i in range(4, 7):
            assert not pipe.process(src.render(i)).errors
    finally:
        pipe.hands.close()


def test_a_staged_frame_is_sent_without_a_copy_and_gives_the_same_hands():
    """Frames staged ahead of their step (:meth:`HandLoop.stage`, the frame reader's copy into the shared memory) give
    the hands of the step run in this process; the staged copy is the one sent: the caller's array changed after
    staging does not reach the child. A staged frame that never comes is dropped, and frames that were not staged are
    copied as before."""
    here, there = _loop("thread", "off"), _loop("process", "lagged")
    try:
        staged = 0
        for k in range(16):
            frame = _entering_palm(k)
            sent = frame.copy()
            if there.stage(sent, None):
                staged += 1
                sent[:] = 0  # after staging: the child must still see the frame
            if k == 9:
                assert there.stage(_entering_palm(3), None)  # a frame that never comes
            if k == 12:
                sent = frame.copy()  # another array than the staged one: copied at submit
            here.start(frame, None, None, {})
            there.start(sent, None, None, {})
            there.wait()
            assert [e.box for e in there.estimates] == [e.box for e in here.estimates]
            for a, b in zip(there.estimates, here.estimates, strict=True):
                assert np.array_equal(a.state, b.state) and a.score == b.score
            for tid, m in here.masks.items():
                assert np.array_equal(there.masks[tid], m)
        assert staged == 15  # every frame after the first (no process before it; frame 12's copy is not sent)
        assert here.estimates
    finally:
        there.close()


def test_staging_never_writes_the_childs_current_or_previous_frame():
    """The slot bookkeeping of :class:`HandProcess` (no child needed): whatever the order of stages and sends, a frame
    is written only into a slot that is neither of the last two sent nor another staged frame's, at most
    :data:`MAX_STAGED` frames are staged, a send finds its staged slot, and older staged frames are dropped."""
    from multiprocessing.shared_memory import SharedMemory

    from tracker.hands.process import MAX_STAGED, SLOTS
    from tracker.sources.frame_slots import frame_bytes, frame_slots

    proc = HandProcess([], Intrinsics(fx=50.0, fy=50.0, cx=7.5, cy=5.5, width=16, height=12), HandLoopConfig())
    shm = SharedMemory(create=True, size=SLOTS * frame_bytes(12, 16))
    try:
        proc._res.shm, proc._slots = shm, frame_slots(shm, SLOTS, 12, 16)
        rng = np.random.default_rng(24)
        frames = [(np.full((12, 16, 3), k % 256, np.uint8), np.full((12, 16), k, np.float32)) for k in range(400)]
        nxt, staged_idx = 0, []
        for _ in range(600):
            if rng.random() < 0.5 and nxt < len(frames) - 1:
                c, d = frames[nxt + len(staged_idx)] if nxt + len(staged_idx) < len(frames) else frames[-1]
                before = (list(proc._sent), dict(proc._staged))
                ok = proc.stage(c, d)
                assert ok == (len(before[1]) < MAX_STAGED)
                if ok:
                    slot = next(k for k, v in proc._staged.items() if v[1] is c)
                    assert slot not in before[0] and slot not in before[1]
                    assert (proc._slots[slot][0] == c).all() and (proc._slots[slot][1] == d).all()
                    staged_idx.append(nxt + len(staged_idx))
            elif nxt < len(frames):
                c, d = frames[nxt]
                before = list(proc._sent)
                was_staged = bool(staged_idx) and staged_idx[0] == nxt
                slot = proc._take_slot(c, d)
                assert slot not in before
                assert (proc._slots[slot][0] == c).all() and (proc._slots[slot][1] == d).all()
                staged_idx = staged_idx[1:] if was_staged else []
                assert len(proc._staged) == len(staged_idx)
                nxt += 1
        assert nxt > 100
    finally:
        proc._res.shm = None
        proc.close()
        shm.close()
        shm.unlink()
