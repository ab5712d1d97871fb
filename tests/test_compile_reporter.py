"""A child that compiles kernels says so, and its parent waits past the start timeout while it does."""

from __future__ import annotations

import multiprocessing as mp
import threading
import time

import numba as nb

from tracker.compile_reporter import CompileReporter, receive_past_compiles


class _Pipe:
    def __init__(self) -> None:
        self.sent: list = []

    def send(self, msg) -> None:
        self.sent.append(msg)


def test_a_compiling_child_is_waited_for_past_the_timeout():
    """Compile messages 0.5 s apart for 3 s, then "ready": a 1.5 s timeout is restarted by each one, so the ready
    message is returned after twice the timeout; the compile messages themselves are never returned."""
    parent, child = mp.Pipe()

    def child_side() -> None:
        for k in range(6):
            child.send(("compiling", f"kernel_{k}"))
            time.sleep(0.5)
        child.send(("ready",))

    t = threading.Thread(target=child_side)
    t0 = time.monotonic()
    t.start()
    try:
        assert receive_past_compiles(parent, 1.5) == ("ready",)
        assert time.monotonic() - t0 > 1.5 * 1.9
    finally:
        t.join()


def test_a_silent_child_times_out():
    parent, _child = mp.Pipe()
    assert receive_past_compiles(parent, 0.05) is None


def test_the_reporter_stops_after_unregister():
    """Registered, a compile sends ("compiling", name); unregistered, a new compile sends nothing."""

    @nb.njit
    def _kernel_for_this_test(x):
        return 2 * x + 5

    pipe = _Pipe()
    reporter = CompileReporter(pipe).register()
    try:
        assert _kernel_for_this_test(1) == 7
    finally:
        reporter.unregister()
    assert pipe.sent == [("compiling", _kernel_for_this_test.py_func.__qualname__)]
    reporter._last = -float("inf")
    assert _kernel_for_this_test(1.5) == 8.0  # a new signature compiles, unheard
    assert len(pipe.sent) == 1
