"""The hand step in a child process of its own (``HandLoopConfig.worker`` "process"; product addition).

Why: in the server the hand step ran in a thread of the server process, which already keeps most of the 2 cores busy
(pipeline thread, websocket, JPEG); the step's Python parts then compete with the pipeline thread for the global
interpreter lock, and its wall time was twice its CPU time. A child process has its own interpreter lock.

:class:`HandProcess` starts (``spawn``) a child that owns a :class:`~tracker.hands.loop.HandLoop` running in its own
thread (``overlap`` "off") and runs :meth:`HandLoop.step` on the frames it is sent:

* Frames go through shared memory: :data:`SLOTS` slots of colour (uint8 H×W×3) and depth (float32 H×W, metres); a
  frame is written into a slot that is neither the last nor the one before it sent to the child, so that the frame
  the child keeps as its previous frame is never overwritten while it is still read. The table plane and the parts'
  poses go over a pipe (small).
* Staging (session 31): :meth:`HandProcess.stage` copies a frame into a free slot ahead of its turn, from another
  thread (the server's frame reader, :meth:`tracker.pipeline.AssemblyPipeline.prepare`, while the pipeline thread
  processes the frame before); :meth:`HandProcess.submit` of the same arrays then sends that slot without copying
  (about 0.2–0.4 ms of the pipeline thread a frame). The child gets the same pixels either way. At most
  :data:`MAX_STAGED` frames are staged; a staged frame older than one submitted is dropped (never sent), and a frame
  that was not staged is copied at submit as before (and drops every staged one).
* Results come back over the pipe, compact: the estimates, every hand mask M_k and the occluder masks H_k as the
  crop of their bounding rectangle (working resolution for the hand masks, full resolution for H_k), the step's wall
  and thread CPU time. :func:`hand_masks_from` / :func:`mask_from` rebuild the full-resolution bool images, equal
  to those of the step run in the caller's process.
* Errors: an exception of the step (a bad frame) comes back and is raised again by :meth:`HandProcess.result` with
  its type (built-in types; others as RuntimeError), and the child keeps running. A child that dies (crash, killed)
  or does not answer within ``step_timeout`` seconds (a new child's first step: ``start_timeout``, as it loads the
  compiled kernels; so does a step during which the child says it compiles kernels,
  :class:`~tracker.compile_reporter.CompileReporter`) is reported by :class:`HandProcessError` from
  :meth:`HandProcess.result` and a new child is started at once; until it is ready (imports, a few seconds), steps
  are refused with a :class:`HandProcessError` that says so, without waiting. The new child is first given the
  session's first frame again (kept by the parent; the skin model's session background is fitted on it, and it is
  assumed hand-free), then the current one: the hands start afresh (tracks restart by automatic initialisation).
  After :data:`MAX_RESTARTS` deaths in a row without a completed step the process is not started again and every
  step reports why. Only the first start waits for the child (``start_timeout``), so that a fresh loop gives the
  same hands as the step run in place.
* :meth:`HandProcess.close` asks the child to end, kills it if it does not within a few seconds, and frees the shared
  memory; it also runs when the object is garbage-collected.
* Reuse: starting a child costs about 2 s of CPU (imports, compiled kernels) and its first step about 2 s more; the
  server builds a new pipeline each time its source loops or is reset. :func:`park` (``HandLoop.close(keep_process=
  True)``) keeps one idle child: it is told to start afresh (:meth:`HandProcess.recycle`: a new ``HandLoop``, the
  state a new child has) and the next ``HandLoop`` with the same parts, intrinsics and configuration takes it
  (:func:`take_parked`) instead of starting one; the hands are the same as with a new child. At most one child is
  parked; it ends when another is parked, when a loop with other parts asks, on :func:`close_parked` or at exit.

Units: pixels of the colour image, metres, camera frame (as :mod:`tracker.hands.loop`).
"""

from __future__ import annotations

import builtins
import multiprocessing as mp
import pickle
import signal
import threading
import weakref
from dataclasses import replace
from multiprocessing.connection import Connection
from multiprocessing.shared_memory import SharedMemory
from typing import Any

import numpy as np

from tracker.compile_reporter import CompileReporter, receive_past_compiles
from tracker.os_names import name_os_thread
from tracker.sources.frame_slots import frame_bytes, frame_slots

MAX_RESTARTS = 5
"""Deaths of the child in a row (no completed step between them) after which it is not started again."""
SLOTS = 5
"""Frame slots in shared memory: the last two sent (the child's current and previous frame), up to
:data:`MAX_STAGED` staged ones, and one always free for a frame that was not staged."""
MAX_STAGED = 2
"""Frames staged at most (:meth:`HandProcess.stage`)."""


class HandProcessError(RuntimeError):
    """The hand process died, hung, is starting again, or was given up; the message says which."""


def _crop(mask: np.ndarray | None) -> tuple[int, int, np.ndarray] | None:
    """(x, y, crop) of the bounding rectangle of a 2-D mask's set pixels; None for None or an empty mask."""
    if mask is None:
        return None
    rows = np.flatnonzero(mask.any(axis=1))
    if not len(rows):
        return None
    cols = np.flatnonzero(mask.any(axis=0))
    y0, y1, x0, x1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    return x0, y0, np.ascontiguousarray(mask[y0:y1, x0:x1])


def mask_from(crop: tuple[int, int, np.ndarray] | None, size: tuple[int, int], scale: int = 1) -> np.ndarray | None:
    """Full-resolution bool image (``size`` = (W, H)) from a crop (x, y, 0/1 image) at a resolution ``scale`` times
    lower (each of its pixels covers ``scale`` × ``scale`` full pixels; what falls past the image is dropped);
    None for None."""
    if crop is None:
        return None
    x, y, img = crop
    W, H = size
    out = np.zeros((H, W), bool)
    if scale > 1:
        img = np.repeat(np.repeat(img, scale, axis=0), scale, axis=1)
    x, y = x * scale, y * scale
    h, w = min(img.shape[0], H - y), min(img.shape[1], W - x)
    if h > 0 and w > 0:
        out[y : y + h, x : x + w] = img[:h, :w].astype(bool)
    return out


def hand_masks_from(crops: dict[int, tuple[int, int, np.ndarray] | None], size: tuple[int, int],
                    scale: int) -> dict[int, np.ndarray]:  # fmt: skip
    """The full-resolution hand masks (bool H×W per track id) from their working-resolution crops (an empty mask:
    None)."""
    W, H = size
    return {tid: np.zeros((H, W), bool) if c is None else mask_from(c, size, scale) for tid, c in crops.items()}


def step_result(loop: Any) -> dict[str, Any]:
    """What a :class:`~tracker.hands.loop.HandLoop` that has just run :meth:`step` hands back to the parent."""
    tracker = loop.tracker
    return {
        "estimates": loop.estimates,
        "masks": {tid: _crop(m) for tid, m in tracker.hand_masks_small().items()},
        "occluder": _crop(loop.occluder),
        "next_occluder": _crop(loop.next_occluder),
        "seconds": loop.step_seconds,
        "size": tracker.full_size,
        "scale": tracker.s,
    }


def _child(conn: Connection, shm_name: str, shape: tuple[int, int], parts: list, intrinsics: Any,
           config: Any) -> None:  # fmt: skip
    """The child: a HandLoop running its steps in place on the frames in shared memory, until told to stop."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the process group: the parent closes this process
    name_os_thread("hand-step")  # the process's name in top / ps (and bench_server's CPU per process)
    shm = None
    try:
        import cv2

        from tracker.hands.loop import HandLoop

        cv2.setNumThreads(1)  # one core for the hand step; the other is the pipeline's (same results, see tests)
        loop = HandLoop(parts, intrinsics, replace(config, overlap="off", worker="thread"))
        shm = SharedMemory(name=shm_name)
        slots = frame_slots(shm, SLOTS, *shape)
        conn.send(("ready",))
        CompileReporter(conn).register()
    except BaseException as exc:  # noqa: BLE001 - opening failed: tell the parent
        try:
            conn.send(("failed", f"{type(exc).__name__}: {exc}"))
        except OSError:
            pass
        if shm is not None:
            shm.close()
        return
    try:
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                return
            if msg is None:
                return
            if msg[0] == "reset":  # a new session (HandProcess.recycle): the state of a newly started child
                try:
                    loop = HandLoop(parts, intrinsics, replace(config, overlap="off", worker="thread"))
                    conn.send(("ready",))
                except Exception as exc:  # noqa: BLE001 - the parent starts a new child
                    conn.send(("failed", f"{type(exc).__name__}: {exc}"))
                continue
            _, slot, has_depth, table_plane, poses = msg
            color, depth = slots[slot]
            try:
                loop.step(color, depth if has_depth else None, table_plane, poses)
                reply: tuple = ("done", step_result(loop))
            except Exception as exc:  # noqa: BLE001 - handed to the parent, the process goes on
                reply = ("error", type(exc).__name__, str(exc))
            conn.send(reply)
    finally:
        del slots
        shm.close()


class _Resources:
    """The child process, its pipe and the shared memory: what :meth:`HandProcess.close` (or the finalizer) frees."""

    def __init__(self) -> None:
        self.proc: Any = None
        self.conn: Connection | None = None
        self.shm: SharedMemory | None = None

    def stop_child(self) -> None:
        proc, conn, self.proc, self.conn = self.proc, self.conn, None, None
        if conn is not None:
            try:
                conn.send(None)
            except OSError:
                pass
            conn.close()
        if proc is not None:
            proc.join(timeout=10.0)
            if proc.is_alive():
                proc.kill()
                proc.join(timeout=2.0)

    def free(self) -> None:
        self.stop_child()
        if self.shm is not None:
            shm, self.shm = self.shm, None
            shm.close()
            try:
                shm.unlink()
            except FileNotFoundError:
                pass


class HandProcess:
    """One hand step at a time in a child process (see the module docstring): :meth:`submit` a frame, then
    :meth:`result` for its step's result (a dict, see :func:`step_result`). ``parts``, ``intrinsics``, ``config``:
    as for :class:`~tracker.hands.loop.HandLoop` (frames must have the intrinsics' size)."""

    def __init__(self, parts: list, intrinsics: Any, config: Any, start_timeout: float = 120.0,
                 step_timeout: float = 20.0) -> None:  # fmt: skip
        self.parts = list(parts)
        self.intrinsics = intrinsics
        self.config = config
        self.start_timeout = float(start_timeout)
        self.step_timeout = float(step_timeout)
        self.shape = (int(intrinsics.height), int(intrinsics.width))
        self.restarts = 0  # children started after the first one
        self.compiles = 0  # "compiling" messages of the children during steps (see CompileReporter)
        self._res = _Resources()
        self._finalizer = weakref.finalize(self, _Resources.free, self._res)
        self._ready = False
        self._stepped = False  # the current child has answered a step (its compiled kernels are loaded)
        self._started_once = False
        self._deaths = 0  # deaths in a row without a completed step
        self._given_up: str | None = None
        self._lock = threading.Lock()  # the slots' bookkeeping and stage's copy (another thread) vs close
        self._sent: list[int] = []  # the slots of the last two frames sent, oldest first
        self._staged: dict[int, tuple[int, np.ndarray, np.ndarray | None]] = {}  # slot -> (sequence, colour, depth)
        self._staged_seq = 0
        self._pending = False
        self._refused: BaseException | None = None
        self._closed = False
        self._first: tuple | None = None  # the session's first frame (colour, depth, table plane, poses), copied
        self._replay = False  # a restarted child is first given the session's first frame

    # ------------------------------------------------------------------ the child
    @property
    def pid(self) -> int | None:
        """The child's process id (None if none runs)."""
        return None if self._res.proc is None else self._res.proc.pid

    def _spawn(self) -> None:
        """Start a child (the shared memory is made once and kept across restarts); does not wait for it."""
        ctx = mp.get_context("spawn")
        H, W = self.shape
        if self._res.shm is None:
            self._res.shm = SharedMemory(create=True, size=SLOTS * frame_bytes(H, W))
            self._slots = frame_slots(self._res.shm, SLOTS, H, W)
        with self._lock:  # a new child has no previous frame; a staged frame's slot stays valid
            self._sent.clear()
        conn, child_conn = ctx.Pipe()
        proc = ctx.Process(target=_child, name="hand-step", daemon=True,
                           args=(child_conn, self._res.shm.name, self.shape, self.parts, self.intrinsics, self.config))
        proc.start()
        child_conn.close()
        self._res.proc, self._res.conn = proc, conn
        self._ready = False
        self._stepped = False
        if self._started_once:
            self.restarts += 1
        self._started_once = True

    def _check_ready(self, timeout: float) -> bool:
        """Whether the child has said it is ready (waits up to ``timeout`` s); raises HandProcessError if it failed."""
        if self._ready:
            return True
        conn = self._res.conn
        assert conn is not None
        try:
            msg = receive_past_compiles(conn, timeout)  # a new session's HandLoop may compile (CompileReporter)
            if msg is None:
                return False
        except (EOFError, OSError):
            msg = ("failed", f"it ended (exit code {self._exitcode()})")
        if msg[0] != "ready":
            self._died(f"the hand process could not start: {msg[1]}")
        self._ready = True
        return True

    def wait_ready(self, timeout: float | None = None) -> bool:
        """Start the child if none runs and wait until it is ready (``timeout`` s, default ``start_timeout``);
        whether it is."""
        if self._given_up is not None or self._closed:
            return False
        if self._res.proc is None:
            self._spawn()
        return self._check_ready(self.start_timeout if timeout is None else timeout)

    def _exitcode(self) -> int | None:
        proc = self._res.proc
        if proc is None:
            return None
        proc.join(timeout=1.0)
        return proc.exitcode

    def _died(self, message: str) -> None:
        """The child died or hung: end it, start the next one (unless given up) and raise HandProcessError."""
        self._res.stop_child()
        self._ready = False
        self._pending = False
        self._deaths += 1
        if self._deaths >= MAX_RESTARTS:
            self._given_up = f"{message}; given up after {self._deaths} failures in a row"
            raise HandProcessError(self._given_up)
        self._spawn()
        self._replay = self._first is not None
        raise HandProcessError(f"{message}; a new hand process is starting (the hands start again)")

    # ------------------------------------------------------------------ steps
    def submit(self, color: np.ndarray, depth: np.ndarray | None, table_plane: Any, poses: dict) -> None:
        """Hand one frame (RGB uint8 H×W×3, depth metres H×W or None) to the child. Never raises: a bad frame or an
        unavailable process is reported by the next :meth:`result`."""
        self._refused = None
        try:
            self._submit(color, depth, table_plane, poses)
        except Exception as exc:  # noqa: BLE001 - reported by result()
            self._refused = exc

    def _submit(self, color: np.ndarray, depth: np.ndarray | None, table_plane: Any, poses: dict) -> None:
        if self._closed:
            raise HandProcessError("the hand process is closed")
        if self._pending:
            raise RuntimeError("hand process: a step is still running (call result() first)")
        if self._given_up is not None:
            raise HandProcessError(self._given_up)
        H, W = self.shape
        color = np.asarray(color)
        if color.shape != (H, W, 3) or color.dtype != np.uint8:
            raise ValueError(f"hand tracker: expected a {H}×{W}×3 uint8 RGB image, got {color.dtype} {color.shape}")
        if depth is not None:
            depth = np.asarray(depth)
            if depth.shape != (H, W):
                raise ValueError(f"hand tracker: expected a {H}×{W} depth image, got {depth.shape}")
        if self._res.proc is None:
            self._spawn()
        if not self._check_ready(self.start_timeout if not self._deaths and not self.restarts else 0.0):
            if not self._deaths and not self.restarts:
                self._died(f"the hand process did not start within {self.start_timeout:.0f} s")
            raise HandProcessError("the hand process is starting again; no hands on this frame")
        if self._first is None:
            self._first = (color.copy(), None if depth is None else depth.copy(), table_plane, dict(poses))
        elif self._replay:  # the session's hand-free first frame, for the skin model's session background
            self._replay = False
            self._send(*self._first)
            try:
                self.result()
            except HandProcessError:
                raise
            except Exception:  # noqa: BLE001 - the first frame's own error was reported when it was first stepped
                pass
        self._send(color, depth, table_plane, poses)

    def stage(self, color: np.ndarray, depth: np.ndarray | None) -> bool:
        """Copy a frame (the arrays :meth:`submit` will be given: RGB uint8 H×W×3, depth H×W or None) into a free slot
        ahead of its turn; may be called from another thread than :meth:`submit`. Whether it was staged (not when
        closed, given up, the shapes or type differ, or :data:`MAX_STAGED` frames are staged already)."""
        H, W = self.shape
        color = np.asarray(color)
        if color.shape != (H, W, 3) or color.dtype != np.uint8 or (depth is not None and np.shape(depth) != (H, W)):
            return False
        with self._lock:
            if self._closed or self._given_up is not None or self._res.shm is None or len(self._staged) >= MAX_STAGED:
                return False
            free = [k for k in range(SLOTS) if k not in self._sent and k not in self._staged]
            slot = free[0]
            self._write(slot, color, depth)
            self._staged_seq += 1
            self._staged[slot] = (self._staged_seq, color, depth)
        return True

    def _write(self, slot: int, color: np.ndarray, depth: np.ndarray | None) -> None:
        """Copy a frame into shared-memory slot ``slot`` (the depth only when given)."""
        slot_color, slot_depth = self._slots[slot]
        slot_color[...] = color
        if depth is not None:
            slot_depth[...] = depth

    def _take_slot(self, color: np.ndarray, depth: np.ndarray | None) -> int:
        """The slot holding this frame: its staged slot (the same arrays; staged frames older than it are dropped, as
        frames are sent in order), else a free one it is copied into (every staged frame is dropped). Marks the slot as
        sent."""
        with self._lock:
            slot = next((k for k, (_, c, d) in self._staged.items() if c is color and d is depth), None)
            if slot is not None:
                seq = self._staged[slot][0]
                self._staged = {k: v for k, v in self._staged.items() if v[0] > seq}
            else:  # not staged: staged frames are dropped (they may never come, e.g. after an error)
                self._staged.clear()
                slot = next(k for k in range(SLOTS) if k not in self._sent)
                self._write(slot, color, depth)
            self._sent = [*self._sent[-1:], slot]
        return slot

    def _send(self, color: np.ndarray, depth: np.ndarray | None, table_plane: Any, poses: dict) -> None:
        """Put the frame into a slot (:meth:`_take_slot`) and ask the child to step it."""
        slot = self._take_slot(color, depth)
        try:
            assert self._res.conn is not None
            self._res.conn.send(("step", slot, depth is not None, table_plane, dict(poses)))
        except OSError:
            self._died(f"the hand process ended (exit code {self._exitcode()})")
        self._pending = True

    def result(self) -> dict[str, Any] | None:
        """The result of the step of the last :meth:`submit` (None if none was submitted since the last result);
        raises what the step raised, or HandProcessError (see the module docstring)."""
        refused, self._refused = self._refused, None
        if refused is not None:
            raise refused
        if not self._pending:
            return None
        conn = self._res.conn
        assert conn is not None
        # a child's first step loads (after an upgrade: compiles) the hand step's kernels, which can take minutes
        # on a busy machine: it gets the start's time, not a step's, or every new child would be ended mid-compile
        # and so does a step during which the child compiles kernels (it says so: CompileReporter), e.g. the first
        # frame with a hand after an upgrade: each "compiling" message gives the step the start's time from then on
        long = max(self.step_timeout, self.start_timeout)
        timeout = self.step_timeout if self._stepped else long
        while True:
            try:
                msg = conn.recv() if conn.poll(timeout) else None
            except (EOFError, OSError):
                self._died(f"the hand process ended during the step (exit code {self._exitcode()})")
            if msg is None or msg[0] != "compiling":
                break
            self.compiles += 1
            timeout = long
        if msg is None:
            self._died(f"the hand process did not answer within {timeout:.0f} s and was ended")
        self._pending = False
        self._deaths = 0
        self._stepped = True
        if msg[0] == "done":
            return msg[1]
        _, kind, text = msg
        exc_type = getattr(builtins, kind, None)
        if not (isinstance(exc_type, type) and issubclass(exc_type, Exception)):
            exc_type, text = RuntimeError, f"{kind}: {text}"
        raise exc_type(text)

    def recycle(self) -> bool:
        """Tell a healthy, idle child to start afresh for a new session (a new ``HandLoop`` in the child; its answer
        is awaited by the next :meth:`submit`, as a new child's); this object then behaves as a new one whose child
        has started. False (nothing sent) if the child is not ready, a step is pending, or it is closed or given up."""
        conn = self._res.conn
        if self._closed or self._given_up is not None or not self._ready or self._pending or conn is None:
            return False
        if self._res.proc is None or not self._res.proc.is_alive():
            return False
        try:
            conn.send(("reset",))
        except OSError:
            return False
        self._ready = False
        self._refused = None
        self._first, self._replay = None, False
        with self._lock:
            self._sent.clear()
            self._staged.clear()
        self._deaths = 0
        self.restarts = 0
        return True

    def close(self) -> None:
        """End the child (politely, then by force) and free the shared memory."""
        with self._lock:  # waits for a stage() copying into the shared memory
            self._closed = True
            self._staged.clear()
        self._pending = False
        self._finalizer()


_parked: list[tuple[bytes, HandProcess]] = []  # at most one idle child, with its key (see park)
_parked_lock = threading.Lock()


def _reuse_key(parts: list, intrinsics: Any, config: Any) -> bytes | None:
    """What a parked child must have been made for to be taken (parts, intrinsics, configuration), None if it cannot
    be told (unpicklable: no reuse)."""
    try:
        return pickle.dumps((list(parts), intrinsics, config), protocol=4)
    except Exception:  # noqa: BLE001 - then the child is not reused
        return None


def park(proc: HandProcess) -> None:
    """Keep ``proc``'s child for the next loop of the same parts, intrinsics and configuration
    (:meth:`HandProcess.recycle`); a child that cannot be recycled is closed, and so is the one parked before."""
    key = _reuse_key(proc.parts, proc.intrinsics, proc.config)
    if key is None or not proc.recycle():
        proc.close()
        return
    with _parked_lock:
        old = list(_parked)
        _parked[:] = [(key, proc)]
    for _, p in old:
        p.close()


def take_parked(parts: list, intrinsics: Any, config: Any) -> HandProcess | None:
    """The parked child if it was made for these parts, intrinsics and configuration (it is no longer parked); None
    otherwise (a parked child made for others is closed)."""
    key = _reuse_key(parts, intrinsics, config)
    with _parked_lock:
        old = list(_parked)
        _parked.clear()
    for k, p in old:
        if k == key:
            return p
        p.close()
    return None


def close_parked() -> None:
    """End the parked child, if any."""
    take_parked([], None, None)
