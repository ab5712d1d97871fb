"""The pipeline worker: one thread pulls frames from the source, runs the pipeline and keeps the latest Snapshot.

The web server never waits on it: readers take :attr:`PipelineWorker.latest` (only the newest snapshot
is kept, so a slow reader skips frames rather than queueing them) or register a listener that is told
when a new snapshot exists. Commands that touch the pipeline (a drawn box, a new mode) are queued with
:meth:`PipelineWorker.submit` and run on the worker thread between frames.

Errors: a frame that fails (a corrupt frame from the source, or a pipeline exception) is skipped and
reported in :attr:`errors`; after repeated source failures, or when the source ends (with ``loop``) or
dies, it is closed and reopened with a growing delay. Opening failures are reported and retried.
"""

from __future__ import annotations

import bisect
import collections
import json
import logging
import math
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

import cv2

from tracker.frame import Frame, FrameError
from tracker.os_names import name_os_thread
from tracker.pipeline import AssemblyPipeline
from tracker.snapshot import Snapshot
from tracker.sources.base import FrameSource

log = logging.getLogger(__name__)


@dataclass
class WorkerError:
    """A reported problem: wall-clock ``time``, ``where`` (source, frame, pipeline) and the message."""

    time: float
    where: str
    message: str

    def to_dict(self) -> dict[str, Any]:
        return {"time": self.time, "where": self.where, "message": self.message}


class _RandomAccess:
    """A source whose frame ``i`` can be produced directly (the simulator's ``render``, a recording's ``read``).

    ``count`` frames; ``offset(i)``: seconds of frame ``i`` after the first; ``produce(i)``: the Frame.
    ``due(t)``: the newest frame whose time has come ``t`` seconds after the first frame.
    """

    def __init__(self, count: int, offsets: Callable[[int], float], produce: Callable[[int], Frame], fps: float | None):
        self.count = count
        self.offset = offsets
        self.produce = produce
        self.fps = fps
        self._times: list[float] | None = None

    def due(self, t: float) -> int:
        if self.fps:
            return int(math.floor(t * self.fps + 1e-9))
        if self._times is None:
            self._times = [self.offset(i) for i in range(self.count)]
        return bisect.bisect_right(self._times, t) - 1

    @classmethod
    def of(cls, source: FrameSource) -> _RandomAccess | None:
        """The random access of ``source``, or ``None`` when it can only be iterated (cameras, test doubles)."""
        render, read = getattr(source, "render", None), getattr(source, "read", None)
        if callable(render) and isinstance(getattr(source, "n_frames", None), int):
            fps = 30.0
            try:
                fps = float(source.metadata().get("fps") or 30.0)
            except Exception:  # noqa: BLE001 - the nominal simulator rate
                pass
            return cls(int(source.n_frames), lambda i: i / fps, render, fps)
        timestamp = getattr(source, "timestamp", None)
        if callable(read) and callable(timestamp):
            try:
                n = len(source)  # type: ignore[arg-type]
                t0 = float(timestamp(0)) if n else 0.0
            except Exception:  # noqa: BLE001
                return None
            return cls(n, lambda i: float(timestamp(i)) - t0, read, None)
        return None


AHEAD_MAX_S = 0.1
"""``realtime_ahead``: how far ahead of now (s) a paced frame is chosen at most (its production estimate, capped: a
first frame that compiled kernels for seconds must not make the reader skip and hold seconds of frames)."""


class _FramePrefetcher:
    """Reads a source on its own thread so producing the next frame overlaps with processing this one.

    Items are ``("frame", Frame, produce_s, capture_wall, ready_wall, prepared)``, ``("error", exception, ...)`` or
    ``("end", None, ...)``; ``capture_wall`` is the frame's capture time (``time.time()``), ``ready_wall`` when
    it was produced, ``prepared`` what ``prepare(frame)`` returned (None without ``prepare``, for errors and the end):
    work on the frame done on this thread before its turn (the pipeline's :meth:`AssemblyPipeline.prepare`, its colour
    detection), so that it overlaps the processing of the previous frame; not with ``drop_stale``, where most frames
    read are dropped. Its time counts as production time for the just-in-time start below. Three ways of reading:

    * ``drop_stale`` (live cameras): the source is read continuously and a full queue drops its oldest
      frame, so the pipeline always gets the newest one; capture time = when the source returned it.
    * ``realtime`` on a source with random access (the simulator's ``render(i)``, a recording's
      ``read(i)``): frames are due at their own times after the first one; each time the worker needs a
      frame the reader produces the newest frame whose time has come, skipping the stale ones (counted in
      :attr:`dropped`), so latency cannot pile up when the pipeline is slower than the source. Capture
      time = the frame's due time. With ``ahead`` the reader produces the frame that will be due when its
      production ends (the typical production time ahead of now) and hands it over at its due time, not before:
      a camera's frame is there at its due time, while without ``ahead`` a simulated frame is produced only
      once due, so the pipeline waits the render's time for it (``starved``) and the frame is that much older.
    * otherwise on demand: the next frame of the iterator (no frame is lost); capture time = when its
      production started.

    On demand and paced, the next frame is produced *just in time*: production starts when the worker's
    typical frame cycle minus the typical production time has passed since it took the previous frame,
    so the frame is ready when the worker is, instead of waiting (and ageing) in the queue.
    """

    def __init__(self, source: FrameSource, maxsize: int = 1, drop_stale: bool = False, realtime: bool = False,
                 prepare: Callable[[Frame], Any] | None = None, ahead: bool = False) -> None:  # fmt: skip
        self.source = source
        self.ahead = bool(ahead)
        self.prepare = None if drop_stale else prepare
        self.queue: queue.Queue = queue.Queue(maxsize=maxsize)
        self.drop_stale = drop_stale
        self.access = _RandomAccess.of(source) if realtime and not drop_stale else None
        self.dropped = 0
        self._wanted = threading.Semaphore(1)  # on-demand / paced: one frame requested at a time
        self._want_at = 0.0  # perf_counter() time at which production of the requested frame should start
        self._cycle_s = 0.0  # moving average: worker's time from taking one frame to asking for the next
        self._produced: collections.deque[float] = collections.deque(maxlen=30)  # recent production times
        self.starved_s = 0.0  # how long the last get() waited for its frame
        self._taken_at: float | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="frame-reader", daemon=True)
        self._thread.start()

    @staticmethod
    def _average(old: float, new: float) -> float:
        return new if old == 0.0 else 0.8 * old + 0.2 * new

    def _wait_until(self, t: float) -> None:
        delay = t - time.perf_counter()
        if delay > 0:
            self._stop.wait(delay)

    def _run(self) -> None:
        name_os_thread()
        if self.access is not None:
            self._run_paced(self.access)
            return
        try:
            it = iter(self.source)
        except Exception as exc:  # noqa: BLE001 - handed to the worker
            now = time.time()
            self._put(("error", exc, 0.0, now, now, None))
            self._put(("end", None, 0.0, now, now, None))
            return
        while not self._stop.is_set():
            if not self.drop_stale:
                if not self._wanted.acquire(timeout=0.1):
                    continue
                self._wait_until(self._want_at)
            t0, started = time.perf_counter(), time.time()
            try:
                frame = next(it)
            except StopIteration:
                now = time.time()
                self._put(("end", None, 0.0, now, now, None))
                return
            except Exception as exc:  # noqa: BLE001 - a corrupt frame or a failing device: the worker decides
                now = time.time()
                self._put(("error", exc, time.perf_counter() - t0, now, now, None))
                continue
            took = time.perf_counter() - t0
            prepared = self._prepare(frame)
            now = time.time()
            if not self.drop_stale:
                self._produced.append(time.perf_counter() - t0)
            self._put(("frame", frame, took, now if self.drop_stale else started, now, prepared))

    def _run_paced(self, access: _RandomAccess) -> None:
        clock0: float | None = None
        wall0 = 0.0
        last = -1
        while not self._stop.is_set():
            if not self._wanted.acquire(timeout=0.1):
                continue
            self._wait_until(self._want_at)
            if clock0 is None:
                clock0, wall0 = time.perf_counter(), time.time()
            lead = min(self._production_estimate(), AHEAD_MAX_S) if self.ahead else 0.0
            index = max(last + 1, access.due(time.perf_counter() + lead - clock0))
            if index >= access.count:
                now = time.time()
                self._put(("end", None, 0.0, now, now, None))
                return
            if not self.ahead:
                self._wait_until(clock0 + access.offset(index))  # not due yet: the pipeline is faster than the source
            if self._stop.is_set():
                return
            self.dropped += index - last - 1
            last = index
            t0 = time.perf_counter()
            try:
                frame = access.produce(index)
            except Exception as exc:  # noqa: BLE001 - a corrupt frame: the worker decides
                now = time.time()
                self._put(("error", exc, time.perf_counter() - t0, now, now, None))
                continue
            took = time.perf_counter() - t0
            prepared = self._prepare(frame)
            self._produced.append(time.perf_counter() - t0)
            if self.ahead:
                self._wait_until(clock0 + access.offset(index))  # made before its due time: handed over when due
                if self._stop.is_set():
                    return
            self._put(("frame", frame, took, wall0 + access.offset(index), time.time(), prepared))

    def _prepare(self, frame: Any) -> Any:
        """``prepare(frame)`` (None without it or if it raises: the pipeline then does the work itself)."""
        if self.prepare is None:
            return None
        try:
            return self.prepare(frame)
        except Exception:  # noqa: BLE001 - the pipeline does the work on its own thread instead
            return None

    def _put(self, item: tuple) -> None:
        while not self._stop.is_set():
            if self.drop_stale and item[0] == "frame":
                try:
                    self.queue.put_nowait(item)
                    return
                except queue.Full:
                    try:
                        old = self.queue.get_nowait()
                        if old[0] == "frame":
                            self.dropped += 1
                        else:  # never drop an error or the end: put it back in front of this frame
                            self.queue.put_nowait(old)
                            self._stop.wait(0.01)
                    except (queue.Empty, queue.Full):
                        pass
                    continue
            try:
                self.queue.put(item, timeout=0.1)
                return
            except queue.Full:
                continue

    def _production_estimate(self) -> float:
        """A pessimistic production time: the 80th percentile of the recent ones (0 before the first)."""
        if not self._produced:
            return 0.0
        times = sorted(self._produced)
        return times[int(0.8 * (len(times) - 1))]

    def get(self, timeout: float) -> tuple | None:
        asked = time.perf_counter()
        if self._taken_at is not None:
            cycle = asked - self._taken_at
            if cycle < 1.0:  # pauses and commands are not part of the frame cycle
                self._cycle_s = self._average(self._cycle_s, cycle)
            self._taken_at = None
        try:
            item = self.queue.get(timeout=timeout)
        except queue.Empty:
            return None
        taken = time.perf_counter()
        self.starved_s = taken - asked
        self._taken_at = taken
        if not self.drop_stale:
            lead = self._cycle_s - self._production_estimate() - 0.004
            self._want_at = taken + max(0.0, lead)
            self._wanted.release()  # the next frame is produced while this one is processed
        return item

    def close(self, timeout: float = 2.0) -> None:
        self._stop.set()
        self._thread.join(timeout)


class PipelineWorker:
    """Runs ``make_pipeline(source)`` on frames of ``open_source()`` in a background thread.

    * ``open_source``: returns a fresh :class:`FrameSource` (called again to reopen).
    * ``make_pipeline``: builds the :class:`AssemblyPipeline` for a freshly opened source.
    * ``max_fps``: upper bound on processed frames per second (the worker sleeps the rest).
    * ``loop``: reopen the source when it ends (recordings and the simulator run forever).
    * ``max_consecutive_errors``: source failures in a row before the source is reopened.
    * ``drop_stale``: for live cameras, read continuously and skip frames that waited while the pipeline
      was busy.
    * ``realtime``: pace sources with random access (simulator, recordings; open them *unpaced*) at their
      own frame rate, always processing the newest due frame and skipping stale ones.
    * ``prepare_ahead``: the frame reader runs the pipeline's :meth:`~AssemblyPipeline.prepare` (the colour
      detection) on each frame it produces, so that work overlaps the previous frame's processing instead of
      lengthening the pipeline thread's cycle (the snapshots are the same; not with ``drop_stale``).
    * ``realtime_ahead`` (with ``realtime``): produce each paced frame ahead of its due time and hand it over when
      due (:class:`_FramePrefetcher` ``ahead``), as a camera delivers it, instead of starting its production then.

    Frames are read on a second thread (:class:`_FramePrefetcher`), so the source's work overlaps the
    pipeline's; ``Snapshot.wall_time`` is the frame's capture time (see there), so ``time.time() -
    wall_time`` on receipt is the honest frame → client latency.
    """

    def __init__(
        self,
        open_source: Callable[[], FrameSource],
        make_pipeline: Callable[[FrameSource], AssemblyPipeline],
        max_fps: float | None = 30.0,
        loop: bool = True,
        max_consecutive_errors: int = 5,
        reopen_delay_s: float = 0.5,
        drop_stale: bool = False,
        realtime: bool = False,
        prepare_ahead: bool = True,
        realtime_ahead: bool = False,
    ) -> None:
        self._open_source = open_source
        self._make_pipeline = make_pipeline
        self.max_fps = max_fps
        self.loop = loop
        self.max_consecutive_errors = int(max_consecutive_errors)
        self.reopen_delay_s = float(reopen_delay_s)
        self.drop_stale = bool(drop_stale)
        self.realtime = bool(realtime)
        self.prepare_ahead = bool(prepare_ahead)
        self.realtime_ahead = bool(realtime_ahead)

        self.source: FrameSource | None = None
        self.pipeline: AssemblyPipeline | None = None
        self._published: tuple[int, Snapshot | None, Frame | None] = (0, None, None)
        self.frames_processed = 0
        self.frames_skipped = 0
        self.source_opens = 0
        self.state = "stopped"
        self.errors: collections.deque[WorkerError] = collections.deque(maxlen=100)

        self._reader: _FramePrefetcher | None = None
        self._frames_dropped_before = 0
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._running = threading.Event()
        self._wake = threading.Event()
        self._reset_requested = False
        self._commands: queue.Queue[tuple[Callable[[AssemblyPipeline | None, Frame | None], Any], Future]] = (
            queue.Queue()
        )
        self._listeners: list[Callable[[Snapshot], None]] = []
        self.frame_hooks: list[Callable[[Snapshot, Frame], None]] = []
        """``hook(snapshot, frame)`` runs on the worker thread after each frame, before the snapshot is published
        (it may add to the snapshot, e.g. identical parts told apart in the image)."""
        self._lock = threading.Lock()
        self._jpeg_cache: tuple[int, int, bytes] | None = None  # (version, quality, JPEG)
        self._json_cache: tuple[int, str] | None = None

    # ------------------------------------------------------------------ control (any thread)
    def start(self) -> None:
        """Start (or resume) processing; starts the thread on first call."""
        self._running.set()
        self._wake.set()
        if self._thread is None or not self._thread.is_alive():
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="pipeline-worker", daemon=True)
            self._thread.start()

    def pause(self) -> None:
        self._running.clear()
        self._wake.set()

    def reset(self) -> None:
        """Reopen the source and rebuild the pipeline (on the worker thread, before the next frame)."""
        self._reset_requested = True
        self._wake.set()

    def stop(self, timeout: float = 5.0) -> None:
        """Stop the thread and close the source."""
        self._stop.set()
        self._running.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join(timeout)
        self._close_source()
        if self._thread is None or not self._thread.is_alive():
            self._close_pipeline(keep_hand_process=False)
            from tracker.hands.process import close_parked

            close_parked()
        self.state = "stopped"

    @property
    def published(self) -> tuple[int, Snapshot | None, Frame | None]:
        """``(version, snapshot, frame)`` of the newest processed frame, read consistently."""
        return self._published

    @property
    def latest(self) -> Snapshot | None:
        return self._published[1]

    @property
    def latest_frame(self) -> Frame | None:
        return self._published[2]

    @property
    def version(self) -> int:
        return self._published[0]

    @property
    def paused(self) -> bool:
        return not self._running.is_set()

    def submit(self, fn: Callable[[AssemblyPipeline | None, Frame | None], Any]) -> Future:
        """Run ``fn(pipeline, latest_frame)`` on the worker thread between frames; returns its Future."""
        fut: Future = Future()
        if self._thread is None or not self._thread.is_alive():
            try:
                fut.set_result(fn(self.pipeline, self.latest_frame))
            except Exception as exc:  # noqa: BLE001 - handed to the caller through the future
                fut.set_exception(exc)
            return fut
        self._commands.put((fn, fut))
        self._wake.set()
        return fut

    def add_listener(self, callback: Callable[[Snapshot], None]) -> None:
        """``callback(snapshot)`` runs on the worker thread after each frame: it must return at once."""
        with self._lock:
            self._listeners.append(callback)

    def remove_listener(self, callback: Callable[[Snapshot], None]) -> None:
        with self._lock:
            if callback in self._listeners:
                self._listeners.remove(callback)

    def report(self, where: str, message: str) -> None:
        log.warning("%s: %s", where, message)
        self.errors.append(WorkerError(time.time(), where, message))

    def status(self) -> dict[str, Any]:
        snap = self.latest
        return {
            "state": self.state,
            "paused": self.paused,
            "frames_processed": self.frames_processed,
            "frames_skipped": self.frames_skipped,
            "frames_dropped": self.frames_dropped,
            "source_opens": self.source_opens,
            "frame_index": None if snap is None else snap.frame_index,
            "fps": 0.0 if snap is None else round(snap.fps, 2),
            "errors": [e.to_dict() for e in list(self.errors)[-10:]],
        }

    @property
    def frames_dropped(self) -> int:
        """Stale frames skipped because the pipeline was busy (``drop_stale`` or ``realtime``)."""
        reader = self._reader
        return self._frames_dropped_before + (reader.dropped if reader is not None else 0)

    def snapshot_json(self) -> tuple[int, str] | None:
        """``(version, JSON text)`` of the newest snapshot, encoded once however many clients read it."""
        version, snap, _frame = self._published
        if snap is None:
            return None
        return self._json_of(version, snap)

    def jpeg(self, quality: int = 75) -> tuple[int, bytes] | None:
        """The latest colour image as JPEG ``(frame_index, bytes)``, encoded once per frame."""
        version, _snap, frame = self._published
        if frame is None:
            return None
        data = self._jpeg_of(version, frame, quality)
        return None if data is None else (frame.index, data)

    def frame_message(self, with_image: bool, quality: int = 75) -> tuple[int, str, bytes | None] | None:
        """``(version, snapshot JSON, JPEG of its colour image or None)`` of the newest frame, both from the same
        published frame (read once), so a client showing them together shows one consistent state. Each is
        encoded once per frame however many clients read it. ``None`` before the first frame."""
        version, snap, frame = self._published
        if snap is None:
            return None
        image = self._jpeg_of(version, frame, quality) if with_image and frame is not None else None
        return version, self._json_of(version, snap)[1], image

    def _json_of(self, version: int, snap: Snapshot) -> tuple[int, str]:
        cache = self._json_cache
        if cache is not None and cache[0] == version:
            return cache
        payload = snap.to_dict()
        payload["worker"] = {"state": self.state, "paused": self.paused}
        cache = (version, json.dumps(payload, separators=(",", ":"), allow_nan=False))
        self._json_cache = cache
        return cache

    def _jpeg_of(self, version: int, frame: Frame, quality: int) -> bytes | None:
        cache = self._jpeg_cache
        if cache is not None and cache[0] == version and cache[1] == quality:
            return cache[2]
        ok, buf = cv2.imencode(
            ".jpg", cv2.cvtColor(frame.color, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality]
        )
        if not ok:
            return None
        data = buf.tobytes()
        self._jpeg_cache = (version, quality, data)
        return data

    # ------------------------------------------------------------------ the worker thread
    def _close_source(self) -> None:
        src, reader = self.source, self._reader
        self.source, self._reader = None, None
        if reader is not None:
            reader.close()
            self._frames_dropped_before += reader.dropped
        if src is not None:
            try:
                src.close()
            except Exception as exc:  # noqa: BLE001
                self.report("source", f"closing failed: {exc}")

    def _close_pipeline(self, keep_hand_process: bool) -> None:
        """End the pipeline's hand step (see :meth:`AssemblyPipeline.close`): before a new pipeline replaces it
        (``keep_hand_process``: the new one of the same parts takes the hand process), or when the worker stops."""
        close = getattr(self.pipeline, "close", None)
        if callable(close):
            try:
                close(keep_hand_process=keep_hand_process)
            except Exception as exc:  # noqa: BLE001 - reported; the next pipeline starts its own
                self.report("pipeline", f"closing failed: {type(exc).__name__}: {exc}")

    def _open(self) -> bool:
        self._close_source()
        self._close_pipeline(keep_hand_process=True)
        self.state = "starting"
        try:
            src = self._open_source()
        except Exception as exc:  # noqa: BLE001 - reported, retried
            self.report("source", f"cannot open: {exc}")
            return False
        try:
            pipeline = self._make_pipeline(src)
        except Exception as exc:  # noqa: BLE001
            self.report("pipeline", f"cannot build: {type(exc).__name__}: {exc}")
            try:
                src.close()
            except Exception:  # noqa: BLE001, S110
                pass
            return False
        self.source, self.pipeline = src, pipeline
        self._reader = _FramePrefetcher(src, drop_stale=self.drop_stale, realtime=self.realtime,
                                        prepare=getattr(pipeline, "prepare", None) if self.prepare_ahead else None,
                                        ahead=self.realtime_ahead)  # fmt: skip
        self.source_opens += 1
        self.state = "running"
        return True

    def _run_commands(self) -> None:
        while True:
            try:
                fn, fut = self._commands.get_nowait()
            except queue.Empty:
                return
            if not fut.set_running_or_notify_cancel():
                continue
            try:
                fut.set_result(fn(self.pipeline, self.latest_frame))
            except Exception as exc:  # noqa: BLE001 - handed to the caller
                fut.set_exception(exc)

    def _sleep(self, seconds: float) -> None:
        self._wake.wait(timeout=max(0.0, seconds))
        self._wake.clear()

    def _publish(self, snap: Snapshot, frame: Frame) -> None:
        self._published = (self._published[0] + 1, snap, frame)  # one assignment: readers see a consistent triple
        with self._lock:
            listeners = list(self._listeners)
        for cb in listeners:
            try:
                cb(snap)
            except Exception as exc:  # noqa: BLE001
                log.warning("snapshot listener failed: %s", exc)

    def _run(self) -> None:
        name_os_thread()
        delay = self.reopen_delay_s
        consecutive = 0
        while not self._stop.is_set():
            self._run_commands()
            if self._reset_requested:
                self._reset_requested = False
                self._close_source()
            if not self._running.is_set():
                if self.state == "running":
                    self.state = "paused"
                self._sleep(0.2)
                continue
            if self._reader is None:
                if not self._open():
                    self.state = "error"
                    self._sleep(delay)
                    delay = min(delay * 2, 5.0)
                    continue
                delay = self.reopen_delay_s
                consecutive = 0
            self.state = "running"
            t_start = time.perf_counter()
            item = self._reader.get(timeout=0.2)
            if item is None:
                continue  # no frame yet: look at commands and pause again
            kind, payload, read_s, captured, ready, prepared = item
            if kind == "end":
                if consecutive:
                    self.report("source", "source stopped after an error; reopening")
                elif self.loop:
                    log.info("source ended; reopening (loop)")
                else:
                    self.state = "finished"
                    self._running.clear()
                    self._close_source()
                    continue
                self._close_source()
                continue
            if kind == "error":
                exc = payload
                consecutive += 1
                self.frames_skipped += 1
                self.report("source", f"frame skipped: {type(exc).__name__}: {exc}")
                if consecutive >= self.max_consecutive_errors:
                    self.report("source", f"{consecutive} failures in a row; reopening the source")
                    self._close_source()
                    self._sleep(delay)
                continue
            frame = payload
            consecutive = 0
            waited = max(0.0, time.time() - ready)
            try:
                if not isinstance(frame, Frame):
                    raise FrameError(f"source yielded {type(frame).__name__}, not a Frame")
                frame.validate()
                if prepared is not None:
                    snap = self.pipeline.process(frame, wall_time=captured, prepared=prepared)
                else:
                    snap = self.pipeline.process(frame, wall_time=captured)
                snap.timings["source"] = read_s  # producing the frame (overlapped with the previous frame)
                snap.timings["wait"] = waited  # from the end of the frame's production to the start of its processing
                snap.timings["starved"] = self._reader.starved_s  # the worker waited this long for the frame
                for hook in self.frame_hooks:
                    hook(snap, frame)
            except Exception as exc:  # noqa: BLE001 - the frame is skipped, the worker goes on
                self.frames_skipped += 1
                self.report("frame", f"frame {getattr(frame, 'index', '?')} skipped: {type(exc).__name__}: {exc}")
                continue
            self.frames_processed += 1
            self._publish(snap, frame)
            if self.max_fps:
                rest = 1.0 / self.max_fps - (time.perf_counter() - t_start)
                if rest > 0:
                    self._stop.wait(rest)
        self.state = "stopped"
