"""Decode a recording's next frames in a background thread while the current one is processed.

A 640×480 frame's colour and depth PNGs take about 5 ms of CPU to decode (:mod:`tracker.sources.png_decode`, whose
inflate and filter loop release the GIL; 8–12 ms with ``cv2.imdecode``).
Read sequentially, as ``track``, ``odometry`` and ``hands`` read a recording, that decoding adds to every frame's
wall time; on a machine with a second core, decoding the next frames while the tracker works on this one takes it
off the critical path.

:class:`DecodePrefetcher` keeps the decoded images of up to ``depth`` positions ahead of the last one asked for. It
never changes what a read returns: a prefetched result is the output of the same decode function on the same file,
and a prefetch that failed (a missing or corrupt image, a file not yet written) is not reused — the reader decodes
that position again itself, so its error (or its success, if the file has appeared since) is the synchronous one.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Generic, TypeVar

T = TypeVar("T")


class DecodePrefetcher(Generic[T]):
    """Background decoding of positions ``p + 1 … p + depth`` after each read of position ``p``.

    * ``decode(position)``: the (thread-safe) function that decodes one position; its exceptions are not kept.
    * ``size``: number of positions (reads ahead wrap around modulo ``size`` when ``wrap``, else stop at the end).
    * ``depth``: how many positions ahead to decode (0 disables prefetching: every read decodes synchronously).
    """

    def __init__(self, decode: Callable[[int], T], size: int, depth: int = 2, wrap: bool = False) -> None:
        if depth < 0:
            raise ValueError(f"prefetch depth must be >= 0, got {depth}")
        self._decode = decode
        self._size = int(size)
        self._depth = int(depth)
        self._wrap = bool(wrap)
        self._pending: dict[int, Future] = {}
        self._lock = threading.Lock()
        self._pool: ThreadPoolExecutor | None = None
        self._closed = False

    def get(self, position: int) -> T:
        """The decoded ``position`` (prefetched when it was asked for in time), then schedule the next ones."""
        with self._lock:
            fut = self._pending.pop(position, None)
        value: T | None = None
        if fut is not None:
            try:
                value = fut.result()
            except Exception:  # noqa: BLE001 - decoded again below, synchronously, for its own error
                value = None
        if value is None:
            value = self._decode(position)
        self._schedule(position)
        return value

    def _ahead(self, position: int) -> list[int]:
        out = []
        for k in range(1, self._depth + 1):
            q = position + k
            if q >= self._size:
                if not self._wrap or self._size == 0:
                    break
                q %= self._size
            if q != position and q not in out:
                out.append(q)
        return out

    def _schedule(self, position: int) -> None:
        if self._depth == 0:
            return
        wanted = self._ahead(position)
        with self._lock:
            if self._closed:  # checked under the lock: a close() from another thread cannot be undone here
                return
            # a jump (random access) leaves earlier prefetches unused: drop them so memory stays bounded
            for q in [q for q in self._pending if q not in wanted]:
                self._pending.pop(q).cancel()
            if self._pool is None:
                self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="recording-decode")
            for q in wanted:
                if q not in self._pending:
                    self._pending[q] = self._pool.submit(self._decode, q)

    @property
    def pending(self) -> list[int]:
        """Positions being (or already) decoded ahead, in no particular order."""
        with self._lock:
            return list(self._pending)

    def close(self) -> None:
        """Cancel what is queued and stop the thread (reads after this decode synchronously)."""
        with self._lock:
            self._closed = True
            for fut in self._pending.values():
                fut.cancel()
            self._pending.clear()
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
