"""The camera's path of ``assembly-agent odometry --method fused``, apart from the part tracker.

Per frame k the fused odometry needs two things besides the part tracker's step: frame k's dense alignment, which
needs only the fused path's prediction (so it can run while the tracker steps on frame k), and frame k's fusion
(prediction, table plane, correction), which needs the resting parts of that step (so it can run while the tracker
steps on frame k + 1). :class:`CameraPath` is that state and those jobs; the tracker needs nothing of it.

:class:`CameraPathProcess` runs a :class:`CameraPath` in a child process (``spawn``), so that the part tracker has
the parent's interpreter to itself: in a thread of the same process the two would take turns holding Python's
global lock (the tracker's compiled kernels keep it), and the tracker's step — the part of a frame nothing else can
shorten — would wait for the fusion's Python. Each frame's images go to the child through a ring of shared-memory
slots (the child copies them out at once; a slot is written again only after the fusion of the frame it held),
the rest of each job over a pipe, in frame order; each fusion's result comes back as a
:class:`~concurrent.futures.Future`. A job that fails in the child fails its future with the child's message (and
so does every waiting one if the child ends).

:class:`InlineCameraPath` runs the same jobs at once in the calling thread (the reference a test compares the
process with: the poses are the same to the last bit). Poses: camera → world, world = the first frame's camera frame,
metres; timestamps in seconds.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import threading
import time
from collections import deque
from concurrent.futures import Future, wait
from multiprocessing.shared_memory import SharedMemory
from typing import Any

import numpy as np

from tracker.compile_reporter import CompileReporter, receive_past_compiles
from tracker.sources.frame_slots import frame_bytes, frame_slots


class CameraPath:
    """The dense odometry (the fast settings) and :class:`~tracker.odometry.fused_odometry.FusedOdometry` of one
    recording. ``corners``: each part's corner points (M, 3) in its body frame (metres)."""

    def __init__(self, intrinsics, seed: int, corners: dict[str, np.ndarray]) -> None:
        from tracker.odometry import OdometryConfig, make_odometry
        from tracker.odometry.fused_odometry import FusedOdometry

        self.odometry = make_odometry("default", intrinsics, seed=seed, config=OdometryConfig.fast())
        self.fused = FusedOdometry()
        self.corners = corners
        self._dense: tuple[Any, Any, Any, float] | None = None  # frame, mask, dense result, ms: awaiting fusion

    def dense(self, frame, mask: np.ndarray | None) -> None:
        """Frame k's dense alignment (``mask`` True = exclude), started from the fused path's prediction (not the
        dense odometry's own, which extrapolates a step the fusion rejected); kept for :meth:`fuse`."""
        t0 = time.perf_counter()
        r = self.odometry.step(frame, mask, prior=self.fused.dense_prior(float(frame.timestamp)))
        self._dense = (frame, mask, r, 1e3 * (time.perf_counter() - t0))

    def fuse(self, landmarks: dict, table: tuple[np.ndarray, float] | None):
        """Frame k's fusion, after :meth:`dense`: ``landmarks`` the tracker's resting parts of frame k (part →
        camera-frame pose), ``table`` its table plane ``(normal, offset)`` (camera frame) or None. Returns the
        frame's :class:`~tracker.odometry.odometry_result.OdometryResult` (``ms``: this path's time for the frame,
        ``inliers``: resting parts used)."""
        from tracker.odometry.odometry_result import OdometryResult

        if self._dense is None:
            raise RuntimeError("CameraPath.fuse() needs the frame's dense() first")
        frame, mask, r, ms = self._dense
        self._dense = None
        t0 = time.perf_counter()
        ts = float(frame.timestamp)
        self.fused.predict(ts, r.pose_world_camera if r.ok else None, landmarks, self.corners)
        plane = self.fused.measure_table(frame.depth, frame.intrinsics, mask, guess=table)
        s = self.fused.correct(landmarks, self.corners, plane)
        ok = s.source != "hold"
        return OdometryResult(s.pose, ok, s.used, ms + 1e3 * (time.perf_counter() - t0), ts, message="" if ok else
                              f"frame {frame.index}: no dense pose accepted, no resting part agreed — pose predicted")

    def skip(self, timestamp: float, reason: str):
        """A frame that cannot be measured (``reason``): the pose is extrapolated; its OdometryResult."""
        from tracker.geometry.pose import Pose
        from tracker.odometry.odometry_result import OdometryResult

        self.odometry.skip(timestamp, reason)
        return OdometryResult(self.fused.pose_world_camera or Pose(), False, 0, 0.0, float(timestamp), message=reason)


def _done(value) -> Future:
    fut: Future = Future()
    fut.set_result(value)
    return fut


class InlineCameraPath:
    """A :class:`CameraPath` run at once in the calling thread, with :class:`CameraPathProcess`'s interface."""

    def __init__(self, intrinsics, seed: int, corners: dict[str, np.ndarray]) -> None:
        self.path = CameraPath(intrinsics, seed, corners)

    def dense(self, frame, mask: np.ndarray | None) -> None:
        self.path.dense(frame, mask)

    def fuse(self, landmarks: dict, table) -> Future:
        return _done(self.path.fuse(landmarks, table))

    def skip(self, timestamp: float, reason: str) -> Future:
        return _done(self.path.skip(timestamp, reason))

    def close(self) -> None:
        pass


CHILD_NICENESS = 5
"""The child runs at this lower priority: it has time to spare (its jobs take about half a tracker step), so where
the two cores are full the part tracker's thread — the frame rate — gets the core first."""
SLOTS = 4
"""Shared-memory frame slots of :class:`CameraPathProcess`: how many frames the child may lag behind before the
parent waits for it."""


def _warm_up(intrinsics) -> None:
    """Run a throwaway CameraPath over three synthetic frames (a textured tilted plane moving 2 mm a frame), so that
    the compiled kernels are loaded before the child says it is ready: otherwise the first real frames wait for
    them (about 2 s) and the parent, out of free slots, with them. Nothing of it is kept."""
    from tracker.frame import Frame
    from tracker.geometry.pose import Pose

    h, w = intrinsics.height, intrinsics.width
    v, u = np.mgrid[0:h, 0:w]
    rng = np.random.default_rng(0)
    color = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    path = CameraPath(intrinsics, 0, {"warm-up": np.zeros((8, 3))})
    for k in range(3):
        depth = (0.7 + 0.2 * (v / h) + 0.002 * k).astype(np.float32)
        frame = Frame(k, k / 30.0, color, depth, intrinsics, {})
        path.dense(frame, (u < 8) & (v < 8))
        path.fuse({"warm-up": Pose(np.array([0.0, 0.0, 0.7]), np.array([0.0, 0.0, 0.0, 1.0]))},
                  (np.array([0.0, -0.7071, -0.7071]), 0.6))


def _serve(conn, shm_name: str, intrinsics, seed: int, corners: dict[str, np.ndarray]) -> None:
    """The child: a CameraPath serving the parent's jobs in order, frames read from the shared-memory slots."""
    shm = None
    try:
        from tracker.frame import Frame

        shm = SharedMemory(name=shm_name)
        os.nice(CHILD_NICENESS)
        reporter = CompileReporter(conn).register()  # a cold kernel cache compiles here: minutes, not a hang
        _warm_up(intrinsics)
        path = CameraPath(intrinsics, seed, corners)
        reporter.unregister()
        slots = frame_slots(shm, SLOTS, intrinsics.height, intrinsics.width)
        h, w = intrinsics.height, intrinsics.width
        conn.send(("ready",))
        failed: str | None = None  # a dense step's error, reported with that frame's fusion
        while True:
            msg = conn.recv()
            kind = msg[0]
            if kind == "close":
                conn.send(("closed",))
                return
            try:
                if kind == "dense":
                    _, slot, index, timestamp, packed = msg
                    color, depth = (a.copy() for a in slots[slot])
                    mask = None if packed is None else np.unpackbits(packed, count=h * w).reshape(h, w).astype(bool)
                    path.dense(Frame(index, timestamp, color, depth, intrinsics, {}), mask)
                    continue
                if failed is not None:
                    conn.send(("error", failed))
                    failed = None
                elif kind == "fuse":
                    conn.send(("result", path.fuse(msg[1], msg[2])))
                elif kind == "skip":
                    conn.send(("result", path.skip(msg[1], msg[2])))
            except Exception as exc:  # noqa: BLE001 - told to the parent, which raises it for that frame
                text = f"camera path, {kind}: {type(exc).__name__}: {exc}"
                if kind == "dense":
                    failed = text
                else:
                    conn.send(("error", text))
    except (EOFError, OSError):
        return  # the parent went away
    except Exception as exc:  # noqa: BLE001 - starting failed: tell the parent
        from app.source_process import tell_parent

        tell_parent(conn, exc)
    finally:
        if shm is not None:
            shm.close()


class CameraPathProcess:
    """A :class:`CameraPath` in a child process (see the module docstring); frames of ``intrinsics``' size."""

    def __init__(self, intrinsics, seed: int, corners: dict[str, np.ndarray], start_timeout: float = 120.0) -> None:
        h, w = intrinsics.height, intrinsics.width
        self._hw = (h, w)
        self._shm = SharedMemory(create=True, size=SLOTS * frame_bytes(h, w))
        self._slots = frame_slots(self._shm, SLOTS, h, w)
        self._slot_job: list[Future | None] = [None] * SLOTS  # the fusion of the frame each slot holds
        self._frames = 0
        ctx = mp.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_serve, args=(child, self._shm.name, intrinsics, seed, corners),
                                 name="camera-path", daemon=True)
        self._proc.start()
        child.close()
        self._waiting: deque[Future] = deque()
        self._lock = threading.Lock()
        self._reader: threading.Thread | None = None
        try:
            try:  # a child compiling kernels (a cold cache) says so, and each message restarts the wait
                msg = receive_past_compiles(self._conn, start_timeout)
            except (EOFError, OSError):
                self._proc.join(timeout=5)
                raise RuntimeError("the camera path process ended as it started (exit code "
                                   f"{self._proc.exitcode})") from None
            if msg is None:
                raise RuntimeError(f"the camera path process did not start within {start_timeout:.0f} s "
                                   "(nor said it was compiling kernels)")
            if msg[0] != "ready":
                raise RuntimeError(f"cannot start the camera path process: {msg[1]}")
        except BaseException:
            self.close()
            raise
        self._reader = threading.Thread(target=self._read, name="camera-path-results", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        """Resolve the waiting futures in order with the child's replies."""
        while True:
            try:
                msg = self._conn.recv()
            except (EOFError, OSError):
                self._fail_all(f"the camera path process ended (exit code {self._proc.exitcode})")
                return
            if msg[0] == "closed":
                self._fail_all("the camera path was closed")
                return
            with self._lock:
                fut = self._waiting.popleft()
            if msg[0] == "result":
                fut.set_result(msg[1])
            else:
                fut.set_exception(RuntimeError(msg[1]))

    def _fail_all(self, reason: str) -> None:
        with self._lock:
            while self._waiting:
                self._waiting.popleft().set_exception(RuntimeError(reason))

    def _ask(self, msg: tuple) -> Future:
        fut: Future = Future()
        with self._lock:
            self._waiting.append(fut)
        self._conn.send(msg)
        return fut

    def dense(self, frame, mask: np.ndarray | None) -> None:
        """Frame ``frame``'s dense alignment in the child: its images into the next slot (once the child is done
        with the frame that slot held), ``mask`` (True = exclude) bit-packed with the job."""
        h, w = self._hw
        if frame.depth is None or frame.color.shape[:2] != (h, w) or (mask is not None and mask.shape != (h, w)):
            raise ValueError(f"CameraPathProcess: a frame of {w}x{h} with depth (and a mask of that size) is needed")
        slot = self._frames % SLOTS
        if self._slot_job[slot] is not None:
            wait([self._slot_job[slot]])
        color, depth = self._slots[slot]
        color[...] = frame.color
        depth[...] = frame.depth
        self._conn.send(("dense", slot, frame.index, float(frame.timestamp),
                         None if mask is None else np.packbits(mask, axis=None)))

    def fuse(self, landmarks: dict, table) -> Future:
        """Future of the frame's OdometryResult (:meth:`CameraPath.fuse`)."""
        fut = self._ask(("fuse", landmarks, table))
        self._slot_job[self._frames % SLOTS] = fut
        self._frames += 1
        return fut

    def skip(self, timestamp: float, reason: str) -> Future:
        """Future of a skipped frame's OdometryResult (:meth:`CameraPath.skip`)."""
        return self._ask(("skip", float(timestamp), reason))

    def close(self) -> None:
        """Let the child finish its jobs and stop; waiting futures are resolved first (in order)."""
        if self._proc.is_alive():
            try:
                self._conn.send(("close",))
            except OSError:
                pass
        if self._reader is not None:
            self._reader.join(timeout=60)
        self._proc.join(timeout=10)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join()
        self._conn.close()
        self._slots = []
        self._shm.close()
        self._shm.unlink()
