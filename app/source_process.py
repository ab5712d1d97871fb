"""Render the simulated table in a child process, so rendering and tracking run on two cores in parallel.

The simulator's and the tracker's numba kernels hold Python's global interpreter lock, so in one process
rendering the next frame and tracking this one take turns instead of overlapping. :class:`ProcessSource`
runs a random-access source (anything with ``render(i)`` and ``n_frames``, i.e. the simulator) in a
child process started with ``spawn``; frame ``i`` is requested over a pipe, rendered by the child into
shared memory (colour uint8 H×W×3 and depth float32 H×W metres, one slot: one request at a time) and
copied out by the parent. While the child renders, the asking thread waits on the pipe without holding
the lock. To the worker it looks like the source itself: ``render(i)``, ``n_frames``, ``parts``,
``initial_poses``, ``intrinsics``, ``metadata()`` (with ``fps``), iteration and ``close()``.

Errors: a frame the child cannot render raises :class:`~tracker.sources.base.SourceError` with the child's
message; a child that died (or did not start within ``start_timeout`` seconds) also raises SourceError,
so the worker reports it and reopens the source.
"""

from __future__ import annotations

import multiprocessing as mp
import signal
import threading
from collections.abc import Callable, Iterator
from multiprocessing.connection import Connection
from multiprocessing.shared_memory import SharedMemory
from typing import Any

import numpy as np

from tracker.frame import Frame
from tracker.geometry.camera import Intrinsics
from tracker.os_names import name_os_thread
from tracker.sources.base import FrameSource, SourceError
from tracker.sources.frame_slots import frame_bytes, frame_slots


def _child(conn: Connection, factory: Callable[..., Any], args: tuple, kwargs: dict) -> None:
    """The child process: open the source, describe it, then render requested frames until told to stop."""
    # Ctrl-C in a terminal reaches the whole process group: the parent stops the server and then closes this
    # process (its pipe ends it in any case), so the child does not die under the running worker first.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    name_os_thread("frame-source")  # the process's name in top / ps (and bench_server's CPU per process)
    shm = None
    try:
        src = factory(*args, **kwargs)
        intr = src.intrinsics
        conn.send(
            (
                "ready",
                {
                    "intrinsics": intr.to_dict(),
                    "parts": list(getattr(src, "parts", []) or []),
                    "initial_poses": dict(getattr(src, "initial_poses", {}) or {}),
                    "n_frames": int(src.n_frames),
                    "metadata": src.metadata(),
                    "name": getattr(src, "name", "source"),
                },
            )
        )
        shm_name = conn.recv()
        shm = SharedMemory(name=shm_name)
        w, h = intr.width, intr.height
        ((color, depth),) = frame_slots(shm, 1, h, w)
        while True:
            try:
                msg = conn.recv()
            except EOFError:
                return
            if msg is None:
                return
            try:
                if getattr(src, "renders_into", False):  # straight into the shared memory (no copies)
                    frame = src.render(int(msg), out=(color, depth))
                else:
                    frame = src.render(int(msg))
                if frame.color is not color:
                    color[...] = frame.color
                if frame.depth is None:
                    depth[...] = np.nan
                elif frame.depth is not depth:
                    depth[...] = frame.depth
                conn.send(("frame", frame.index, frame.timestamp, frame.depth is not None, frame.meta))
            except Exception as exc:  # noqa: BLE001 - handed to the parent
                conn.send(("error", f"{type(exc).__name__}: {exc}"))
    except Exception as exc:  # noqa: BLE001 - opening failed: tell the parent
        tell_parent(conn, exc)
    finally:
        if shm is not None:
            shm.close()


def tell_parent(conn, exc: BaseException) -> None:
    """A child process's last word: ``("error", "Type: message")`` to its parent over ``conn`` (nothing when the parent
    has gone)."""
    try:
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
    except OSError:
        pass


class ProcessSource(FrameSource):
    """``factory(*args, **kwargs)`` (picklable; must return a source with ``render(i)`` and ``n_frames``),
    run in a child process. See the module docstring."""

    def __init__(self, factory: Callable[..., Any], *args: Any, start_timeout: float = 120.0, **kwargs: Any) -> None:
        ctx = mp.get_context("spawn")
        self._conn, child_conn = ctx.Pipe()
        self._proc = ctx.Process(
            target=_child, args=(child_conn, factory, args, kwargs), name="frame-source", daemon=True
        )
        self._proc.start()
        child_conn.close()
        self._lock = threading.Lock()
        self._shm: SharedMemory | None = None
        self._closed = False
        try:
            if not self._conn.poll(start_timeout):
                raise SourceError(f"frame source process did not start within {start_timeout:.0f} s")
            msg = self._recv()
            if msg[0] != "ready":
                raise SourceError(f"cannot open the source in its process: {msg[1]}")
            info = msg[1]
            self._intr = Intrinsics.from_dict(info["intrinsics"])
            self.parts = info["parts"]
            self.initial_poses = info["initial_poses"]
            self.n_frames = info["n_frames"]
            self._metadata = info["metadata"]
            self.name = info["name"]
            w, h = self._intr.width, self._intr.height
            self._shm = SharedMemory(create=True, size=frame_bytes(h, w))
            ((self._color, self._depth),) = frame_slots(self._shm, 1, h, w)
            self._conn.send(self._shm.name)
        except BaseException:
            self.close()
            raise

    @property
    def alive(self) -> bool:
        """The child process runs and the source is open."""
        return not self._closed and self._proc.is_alive()

    def _recv(self) -> tuple:
        try:
            return self._conn.recv()
        except (EOFError, OSError) as exc:
            raise SourceError(f"the frame source process ended (exit code {self._proc.exitcode})") from exc

    @property
    def intrinsics(self) -> Intrinsics:
        return self._intr

    def metadata(self) -> dict[str, Any]:
        return {**self._metadata, "process": "child"}

    def render(self, index: int) -> Frame:
        """Frame ``index``, rendered by the child process."""
        with self._lock:
            if self._closed:
                raise SourceError("the frame source is closed")
            try:
                self._conn.send(int(index))
            except OSError as exc:
                raise SourceError(f"the frame source process ended (exit code {self._proc.exitcode})") from exc
            msg = self._recv()
            if msg[0] != "frame":
                raise SourceError(f"frame {index}: {msg[1]}")
            _, idx, timestamp, has_depth, meta = msg
            color = self._color.copy()
            depth = self._depth.copy() if has_depth else None
        return Frame(idx, timestamp, color, depth, self._intr, meta)

    def __len__(self) -> int:
        return self.n_frames

    def __iter__(self) -> Iterator[Frame]:
        for i in range(self.n_frames):
            if self._closed:
                return
            yield self.render(i)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        with self._lock:
            try:
                self._conn.send(None)
            except OSError:
                pass
            self._conn.close()
        self._proc.join(timeout=5.0)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(timeout=2.0)
        if self._shm is not None:
            self._shm.close()
            self._shm.unlink()
            self._shm = None


def open_registry_source(spec: str, seed: int = 0) -> FrameSource:
    """Factory for :class:`ProcessSource`: the registry's source ``spec``, unpaced (the worker paces it)."""
    from tracker.sources.registry import open_source

    return open_source(spec, realtime=False, seed=seed, loop=False)


class SharedView(FrameSource):
    """A :class:`ProcessSource` handed out again: ``close()`` leaves the process running.

    The server reopens a source each time it ends (the simulator loops) or the user resets; with a view of
    one long-lived process that costs nothing instead of starting a new process.
    """

    def __init__(self, source: ProcessSource) -> None:
        self.source = source
        self.name = source.name
        self.parts = source.parts
        self.initial_poses = source.initial_poses
        self.n_frames = source.n_frames

    @property
    def intrinsics(self) -> Intrinsics:
        return self.source.intrinsics

    def metadata(self) -> dict[str, Any]:
        return self.source.metadata()

    def render(self, index: int) -> Frame:
        return self.source.render(index)

    def __len__(self) -> int:
        return self.n_frames

    def __iter__(self) -> Iterator[Frame]:
        return iter(self.source)

    def close(self) -> None:
        """Nothing: the process belongs to whoever made the :class:`ProcessSource`."""
