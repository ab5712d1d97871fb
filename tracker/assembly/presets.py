"""Task presets shipped in ``static/tasks/`` (YAML task files, see :mod:`tracker.assembly.task_file`)."""

from __future__ import annotations

from pathlib import Path

from tracker.assembly.task_file import TaskModel, load_task

PRESET_DIR = Path(__file__).resolve().parents[2] / "static" / "tasks"
"""Directory of the preset task files."""


def list_presets(directory: Path | None = None) -> list[dict]:
    """The presets as ``[{"id", "title", "mode", "path"}]``, sorted by id (invalid files raise ``TaskFileError``)."""
    d = Path(directory) if directory is not None else PRESET_DIR
    out = []
    for path in sorted(d.glob("*.yaml")):
        task = load_task(path)
        out.append({"id": task.id, "title": task.title or task.id, "mode": task.mode, "path": str(path)})
    return out


def preset_path(task_id: str, directory: Path | None = None) -> Path:
    """Path of the preset whose ``id`` (or file stem) is ``task_id``."""
    d = Path(directory) if directory is not None else PRESET_DIR
    direct = d / f"{task_id}.yaml"
    if direct.is_file():
        return direct
    for p in list_presets(d):
        if p["id"] == task_id:
            return Path(p["path"])
    raise ValueError(f"no task preset {task_id!r} in {d} (have: {[p['id'] for p in list_presets(d)]})")


def load_preset(task_id: str) -> TaskModel:
    """Load a preset task by id."""
    return load_task(preset_path(task_id))
