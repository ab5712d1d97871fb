"""Connection events: the time at which two parts were connected or disconnected.

Written by the simulator (ground truth), stored in a recording's ``events.jsonl`` and compared with the
assembly monitor's output by the evaluation. Times are seconds since the source started.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

EVENT_TYPES = ("connected", "disconnected")
"""The valid values of :attr:`ConnectionEvent.type`."""


@dataclass(frozen=True)
class ConnectionEvent:
    """``parts[0]`` and ``parts[1]`` became ``type`` (``"connected"`` / ``"disconnected"``) at ``t`` seconds."""

    t: float
    type: str
    parts: tuple[str, str]

    def __post_init__(self) -> None:
        try:
            t = float(self.t)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"connection event: time must be a number, got {self.t!r}") from exc
        if not math.isfinite(t):
            raise ValueError(f"connection event: time must be finite, got {self.t!r}")
        if self.type not in EVENT_TYPES:
            raise ValueError(f"connection event: type must be one of {EVENT_TYPES}, got {self.type!r}")
        parts = tuple(self.parts) if isinstance(self.parts, list | tuple) else ()
        if len(parts) != 2 or not all(isinstance(p, str) and p for p in parts):
            raise ValueError(f"connection event: parts must be two part names, got {self.parts!r}")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "parts", parts)

    def to_dict(self) -> dict:
        """JSON form ``{"t": 3.2, "type": "connected", "parts": ["a", "b"]}`` (one line of events.jsonl)."""
        return {"t": self.t, "type": self.type, "parts": list(self.parts)}

    @staticmethod
    def from_dict(d: dict) -> ConnectionEvent:
        if not isinstance(d, dict):
            raise ValueError(f"connection event must be an object, got {d!r}")
        missing = [k for k in ("t", "type", "parts") if k not in d]
        if missing:
            raise ValueError(f"connection event: missing field(s) {', '.join(missing)}")
        return ConnectionEvent(d["t"], d["type"], d["parts"])
