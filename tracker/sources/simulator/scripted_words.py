"""Which word goes on which cube in a simulated learning session, so the scripted user builds the right sentence.

The simulator's scripted user builds its row of cubes left to right in a fixed order; the learning mode draws a
random word-to-cube assignment. :func:`scripted_row_assignment` gives the assignment that puts the sentence's
words on the row's cubes in reading order (distractor words on the scenario's distractor cubes), so the
simulated session shows a correct build. Other sources keep the mode's own seeded assignment.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


def scripted_row_assignment(scenario: Mapping[str, Any] | None, mode: Any) -> dict[str, str] | None:
    """Cube → word for a built learning ``mode`` following the scripted row of ``scenario``.

    ``scenario``: the simulator's scenario description (``SimulatedTable.metadata()["scenario"]``: its
    ``structure.cells`` map cube → cell with the column first, and ``distractors``); ``mode``: a learning mode
    with ``sentence`` (``words``, ``distractors``) and ``assignment`` (cube → word). ``None`` when the scenario
    has no row matching the sentence (then the mode's assignment stands).
    """
    scenario = scenario or {}
    cells = (scenario.get("structure") or {}).get("cells") or {}
    row = [c for c, _ in sorted(cells.items(), key=lambda item: item[1][0])]
    words = list(mode.sentence.words)
    if not row or len(row) != len(words) or not set(row) <= set(mode.assignment):
        return None
    assignment = dict(zip(row, words, strict=True))
    spare = [c for c in scenario.get("distractors", []) if c in mode.assignment]
    assignment.update(zip(spare, mode.sentence.distractors, strict=False))
    return assignment
