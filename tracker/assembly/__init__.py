"""Assembly reasoning: task files, relations, cube symmetry, connection monitoring and the three modes.

Public entry points: :func:`load_task`, :func:`list_presets`, :class:`SentenceTask`, :func:`build_mode`
(in :mod:`tracker.assembly.modes`). Poses handed in are camera-frame :class:`~tracker.geometry.pose.Pose` values.
"""

from tracker.assembly.presets import list_presets, load_preset, preset_path
from tracker.assembly.task_file import SentenceTask, TaskFileError, TaskModel, load_task, parse_task

__all__ = [
    "SentenceTask",
    "TaskFileError",
    "TaskModel",
    "list_presets",
    "load_preset",
    "load_task",
    "parse_task",
    "preset_path",
]


def build_mode(*args, **kwargs):
    """See :func:`tracker.assembly.modes.build_mode` (imported lazily)."""
    from tracker.assembly.modes import build_mode as _build

    return _build(*args, **kwargs)


__all__ += ["build_mode"]
