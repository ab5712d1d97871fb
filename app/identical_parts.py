"""Identical parts in the server: several parts of one colour, told apart in the colour image (Algorithm 2).

The user draws one box per part of that colour; :class:`IdenticalParts` keeps a
:class:`~tracker.perception.same_color_tracking.SameColorTracker` for them, updated on every processed frame
(on the worker thread, before the frame's snapshot is published), so each part keeps its identity (``red #1``,
``red #2``, …) through contacts and short occlusions. The result of a frame is in its snapshot's
``identical_parts``: per part ``{"bbox": [x, y, w, h] px, "center": [u, v] | None, "score": 0..1, "seen": bool}``.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

from tracker.perception.same_color_tracking import SameColorTracker

log = logging.getLogger(__name__)

MAX_IDENTICAL = 8
"""At most this many identical parts of one colour."""


class IdenticalParts:
    """The identical parts of one colour being tracked in the image (none until a first box is drawn)."""

    def __init__(self) -> None:
        self.colour: str | None = None
        self.tracker: SameColorTracker | None = None
        self._lock = threading.Lock()

    def add(self, colour: str, hsv_range: Any, rect: tuple[float, float, float, float]) -> str:
        """Track one more part of ``colour`` from its box (x, y, w, h); another colour starts over. Returns
        the new part's name."""
        with self._lock:
            if self.tracker is None or self.colour != colour:
                self.tracker, self.colour = SameColorTracker(hsv_range), colour
                boxes: dict[str, Any] = {}
            else:
                boxes = dict(self.tracker.boxes)
            if len(boxes) >= MAX_IDENTICAL:
                raise ValueError(f"at most {MAX_IDENTICAL} identical parts of one colour")
            name = f"{colour} #{len(boxes) + 1}"
            boxes[name] = rect
            self.tracker.init_boxes(boxes)
            return name

    def clear(self) -> None:
        with self._lock:
            self.tracker, self.colour = None, None

    def names(self) -> list[str]:
        with self._lock:
            return [] if self.tracker is None else list(self.tracker.boxes)

    def on_frame(self, snap, frame) -> None:
        """Update the boxes on ``frame`` and put them into ``snap.identical_parts`` (worker thread)."""
        with self._lock:
            if self.tracker is None:
                return
            try:
                dets = self.tracker.update(frame.color)
            except (RuntimeError, ValueError) as exc:
                log.warning("identical parts: %s", exc)
                return
        snap.identical_parts = {
            name: {
                "bbox": None if d.bbox is None else [int(v) for v in d.bbox],
                "center": None if d.center is None else [float(d.center[0]), float(d.center[1])],
                "score": round(float(d.score), 3),
                "seen": d.center is not None,
            }
            for name, d in dets.items()
        }
