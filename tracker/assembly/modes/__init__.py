"""The three modes and :func:`build_mode`.

Every mode has ``update(t, poses, table_to_camera) -> ModeState`` (camera-frame poses; ``table_to_camera``
maps table-frame points into the camera frame, table y = the upward normal), ``connection_hints()`` (for
the tracker's connection particles) and ``reset()``.
"""

from __future__ import annotations

from collections.abc import Iterable

from tracker.assembly.connection_monitor import AssemblyParams
from tracker.assembly.modes.base import Mode
from tracker.assembly.modes.guess import GuessMode
from tracker.assembly.modes.guidance import GuidanceMode
from tracker.assembly.modes.learning import LearningMode
from tracker.assembly.task_file import TaskModel
from tracker.geometry.parts import PartSpec

MODES = {"guidance": GuidanceMode, "guess": GuessMode, "learning": LearningMode}


def build_mode(task: TaskModel, mode_name: str | None = None, parts: Iterable[PartSpec] | None = None,
               seed: int = 0, params: AssemblyParams | None = None, **kwargs) -> Mode:
    """The mode ``mode_name`` (default: the task's own) for ``task``.

    ``parts``: the source's parts (must include the task's; default the task's parts). ``seed``: the
    learning mode's word assignment and sentence choice. ``kwargs``: mode options (``structure`` for
    guidance, ``sentence`` / ``assignment`` for learning) or parameter overrides (``m_p``, ``K``, ``N_max``,
    ``N_checks``, ``m_q_deg``, ``N_break``, ``break_factor``).
    """
    name = mode_name or task.mode
    if name not in MODES:
        raise ValueError(f"unknown mode {name!r}; choose one of {list(MODES)}")
    if name == "learning":
        return LearningMode(task, parts, params, seed=seed, **kwargs)
    return MODES[name](task, parts, params, **kwargs)


__all__ = ["GuessMode", "GuidanceMode", "LearningMode", "MODES", "Mode", "build_mode"]
