"""Shared plumbing of the three modes (parameters, parts, events, the interface the pipeline uses)."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from tracker.assembly.connection_monitor import AssemblyParams, ConnectionMonitor, MonitorEvent
from tracker.assembly.mode_state import ModeState
from tracker.assembly.relations import table_rotation
from tracker.assembly.task_file import TaskModel
from tracker.filter.connection_hint import ConnectionHint
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose


def resolve_parts(task: TaskModel, parts: Iterable[PartSpec] | None) -> list[PartSpec]:
    """The parts the mode works with: those of the source (``parts``) or, when ``None``, the task's own."""
    if parts is None:
        return task.part_specs()
    parts = list(parts)
    have = {p.name for p in parts}
    missing = [p.name for p in task.parts if p.name not in have]
    if missing:
        raise ValueError(f"task {task.id!r} needs parts {missing} missing from the source (has {sorted(have)})")
    wanted = {p.name for p in task.parts}
    return [p for p in parts if p.name in wanted]


def direction_words(offset_table: np.ndarray) -> str:
    """Words for a table-frame offset (x right, y up, z towards the user): 'to the right of', 'on top of', …"""
    i = int(np.argmax(np.abs(offset_table)))
    pos = offset_table[i] > 0
    words = [("to the right of", "to the left of"), ("on top of", "under"), ("in front of", "behind")]
    return words[i][0 if pos else 1]


class Mode:
    """Base class: ``update(t, poses, table_to_camera) -> ModeState``, ``connection_hints()``, ``reset()``."""

    name = "mode"

    def __init__(self, task: TaskModel, parts: Iterable[PartSpec] | None = None, params: AssemblyParams | None = None,
                 **overrides):
        self.task = task
        self.parts = resolve_parts(task, parts)
        self.params = params or AssemblyParams.from_dict(task.parameters, **overrides)
        self.last_state: ModeState | None = None

    # The monitors whose expected-connection events count for this mode.
    def monitors(self) -> list[ConnectionMonitor]:
        raise NotImplementedError

    def reset(self) -> None:
        for m in self.monitors():
            m.reset()
        self.last_state = None

    def set_hand_contacts(self, touched: Iterable[str] | None) -> None:
        """The parts a hand touches in the coming frame (hand-tracking spec §14.7), for the connection gate of every
        monitor; ``None`` when hands are not tracked (the gate is open)."""
        parts = None if touched is None else {str(p) for p in touched}
        for m in self.monitors():
            m.touched = parts

    def connection_hints(self) -> list[ConnectionHint]:
        """Hints of all monitors; for a pair named by several, the locked one or the one with most particles."""
        best: dict[frozenset, ConnectionHint] = {}
        for m in self.monitors():
            for h in m.connection_hints():
                k = frozenset((h.first, h.second))
                cur = best.get(k)
                if cur is None or (h.locked, h.n_particles) > (cur.locked, cur.n_particles):
                    best[k] = h
        return list(best.values())

    def _update_monitors(self, t: float, poses: dict[str, Pose], table_to_camera: Pose) -> list[dict]:
        """Update every monitor; return the events of this frame as dicts."""
        new = []
        for m in self.monitors():
            n0 = len(m.events)
            m.update(t, poses, table_to_camera)
            new += [e.to_dict() for e in m.events[n0:]]
        return new

    def connection_events(self) -> list[MonitorEvent]:
        """Expected-connection events of all monitors, de-duplicated by (pair, type, time)."""
        seen, out = set(), []
        for m in self.monitors():
            for e in m.events:
                if not e.expected:
                    continue
                k = (frozenset((e.first, e.second)), e.type, round(e.t, 6))
                if k not in seen:
                    seen.add(k)
                    out.append(e)
        return sorted(out, key=lambda e: e.t)

    @staticmethod
    def _table_offset(table_to_camera: Pose, a: Pose, b: Pose) -> np.ndarray:
        return table_rotation(table_to_camera) @ (b.t - a.t)
