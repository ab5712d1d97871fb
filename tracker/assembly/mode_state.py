"""What a mode reports after each frame (:class:`ModeState`, JSON-able through :meth:`ModeState.to_dict`).

Keys of ``to_dict()``: ``mode``, ``task_id``, ``t`` (seconds), ``instruction`` (large-type text for the user),
``progress`` ``{done, total}``, ``complete``, ``connections`` (``[{first, second, state, score, since,
expected}]``, state ``open`` | ``near`` | ``connected``), ``events`` (the monitor's events of this frame) and
the mode's own keys:

* guidance: ``next_step`` ``{part, anchor, target_pose {"t", "q"} (camera frame), direction}`` or ``None``,
  ``warning`` (text or ``None``), ``step`` (index of the current step);
* guess: ``ranking`` ``[{structure, title, completed, total, fraction}]`` (best first), ``guess``,
  ``confidence`` (0..1);
* learning: ``sentence`` (source sentence), ``source_language``, ``words`` ``[{word, cube, is_distractor}]``,
  ``assignment`` ``{cube: word}``, ``row`` (cubes read left to right), ``verdicts``
  ``[{position, expected, placed, correct}]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass
class ModeState:
    mode: str
    task_id: str
    t: float
    instruction: str
    done: int
    total: int
    complete: bool
    connections: list[dict] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return {
            "mode": self.mode,
            "task_id": self.task_id,
            "t": round(float(self.t), 4),
            "instruction": self.instruction,
            "progress": {"done": int(self.done), "total": int(self.total)},
            "complete": bool(self.complete),
            "connections": self.connections,
            "events": self.events,
            **self.extra,
        }
