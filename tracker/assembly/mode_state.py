"""What a mode reports after each frame (:class:`ModeState`, JSON-able through :meth:`ModeState.to_dict`).

Keys of ``to_dict()``: ``mode``, ``task_id``, ``t`` (seconds), ``instruction`` (large-type text for the user),
``progress`` ``{done, total, unit}`` (unit: what is counted — ``steps``, ``connections`` or ``words``),
``complete``, ``connections`` (``[{first, second, state, score, since, expected}]``, state ``open`` | ``near``
| ``connected``), ``events`` (the monitor's events of this frame) and the mode's own keys:

* guidance: ``next_step`` ``{part, anchor, target_pose {"t", "q"} (camera frame), direction}`` or ``None``,
  ``warning`` (text or ``None``), ``step`` (index of the current step);
* guess: ``ranking`` ``[{structure, title, completed, total, fraction}]`` (best first), ``guess``,
  ``confidence`` (0..1), ``tied`` (no single structure leads yet: the instruction says "not sure yet");
* learning: ``sentence`` (source sentence), ``source_language``, ``words`` ``[{word, cube, is_distractor}]``
  (in a shuffled order that does not give the sentence away),
  ``assignment`` ``{cube: word}``, ``row`` (cubes read left to right), ``verdicts``
  ``[{position, expected, placed, correct}]``; progress counts the words in their right place. Once the
  sentence is complete the state (verdict included) stays until the mode is reset (the next round).
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
    unit: str = "connections"

    def to_dict(self) -> dict[str, Any]:
        return {
            "mode": self.mode,
            "task_id": self.task_id,
            "t": round(float(self.t), 4),
            "instruction": self.instruction,
            "progress": {"done": int(self.done), "total": int(self.total), "unit": self.unit},
            "complete": bool(self.complete),
            "connections": self.connections,
            "events": self.events,
            **self.extra,
        }
