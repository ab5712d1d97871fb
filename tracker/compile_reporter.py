"""A child process tells its parent that numba is compiling kernels, so that the parent does not take a long
compile for a hung child.

A kernel compiles on its first call after its source changed (a new checkout, an upgrade, an edit): tens of seconds
of CPU each on a loaded 2-core machine, minutes for a whole path. Children that compile before they answer (the hand
process, the camera path of ``odometry --method fused``) register a :class:`CompileReporter` on numba's compile
event; the parent restarts its wait at each ``("compiling", kernel name)`` message instead of ending the child.
Loading a kernel from numba's cache sends nothing.
"""

from __future__ import annotations

import time
from typing import Any

from numba.core import event as numba_event
from numba.core.event import Listener

COMPILE_REPORT_S = 1.0
"""Seconds between two "compiling" messages (:class:`CompileReporter`): one per kernel would be hundreds after an
upgrade; the parent only needs to hear that the child is still compiling."""


class CompileReporter(Listener):
    """Sends ``("compiling", name)`` over ``conn`` (anything with ``send``) when numba starts compiling a kernel, at
    most one message per :data:`COMPILE_REPORT_S` seconds. A failed send (the parent went away) is ignored."""

    def __init__(self, conn: Any) -> None:
        self.conn = conn
        self._last = -float("inf")

    def on_start(self, event: Any) -> None:
        now = time.monotonic()
        if now - self._last < COMPILE_REPORT_S:
            return
        self._last = now
        try:
            self.conn.send(("compiling", getattr(getattr(event.data.get("dispatcher"), "py_func", None), "__qualname__",
                                                 "?")))
        except (OSError, AttributeError):
            pass

    def on_end(self, event: Any) -> None:
        pass

    def register(self) -> CompileReporter:
        """Listen to numba's compile events from now on (this process); returns self."""
        numba_event.register("numba:compile", self)
        return self

    def unregister(self) -> None:
        """Stop listening (after :meth:`register`)."""
        numba_event.unregister("numba:compile", self)


def receive_past_compiles(conn: Any, timeout: float) -> tuple | None:
    """The first message on ``conn`` (a :class:`multiprocessing.connection.Connection`) that is not a
    ``("compiling", ...)`` one, or None when ``timeout`` seconds pass without any message: each compile message
    restarts the wait. Raises what ``conn.recv`` raises (EOFError, OSError) when the child has gone."""
    while True:
        if not conn.poll(timeout):
            return None
        msg = conn.recv()
        if not (isinstance(msg, tuple) and msg and msg[0] == "compiling"):
            return msg
