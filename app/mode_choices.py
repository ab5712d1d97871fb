"""Mode and source as one choice: which tasks each mode offers, and on which frame source each task can run.

A task runs on a source when the source has every part the task names (a teacher's sentence: at least as many
cubes as the sentence has words and distractors). Besides the current source, each task is offered on the
simulated scenario built for it (:data:`SCENARIO_TASKS`: its scripted user builds that task), so choosing a
mode in the panel switches mode, task and — when needed — the simulated scene together.
"""

from __future__ import annotations

from typing import Any

from app import api_models as m
from tracker.assembly import SentenceTask

SCENARIO_TASKS: dict[str, str] = {
    "guidance-demo": "guidance-5-cubes",
    "guess-1": "guess-structures",
    "guess-2": "guess-structures",
    "guess-3": "guess-structures",
    "learning-4": "learning-4-words",
    "learning-5": "learning-5-words",
}
"""Simulated scenario → the preset task its scripted user builds."""


def scenario_parts() -> dict[str, list[str]]:
    """``sim:<scenario>`` → its part names (empty without the simulator)."""
    try:
        from tracker.sources.simulator import list_scenarios
    except ImportError:
        return {}
    return {f"sim:{sc.name}": list(sc.parts) for sc in list_scenarios()}


def misfit(task: Any, parts: list[str]) -> str | None:
    """Why ``task`` (a TaskModel, a SentenceTask or ``None``) cannot run with ``parts``; ``None`` when it can."""
    if task is None:
        return None
    if isinstance(task, SentenceTask):
        if len(parts) >= len(task.words):
            return None
        return f"the sentence needs {len(task.words)} cubes, the source has {len(parts)}"
    missing = [p.name for p in getattr(task, "parts", []) if p.name not in parts]
    return f"it needs the parts {missing}, missing from the source" if missing else None


def scenarios_for(task_id: str, task: Any) -> list[str]:
    """The simulated sources built for a task (a teacher's sentence of k words: ``sim:learning-k``)."""
    if isinstance(task, SentenceTask):
        spec = f"sim:learning-{len(task.words)}"
        return [spec] if spec in scenario_parts() else []
    return [f"sim:{sc}" for sc, t in SCENARIO_TASKS.items() if t == task_id]


def mode_choices(state: Any, refs: list[m.TaskRef], current_parts: list[str]) -> list[m.ModeChoice]:
    """Every (mode, task, source) the panel offers: each task on the current source when it fits, and on the
    scenarios built for it (first when the current source is a scenario built for something else); "none"
    (tracking only) on the current source."""
    out = [m.ModeChoice(mode="none", task=None, title="tracking only", source=state.source_spec, switches_source=False)]
    sims = scenario_parts()
    for ref in refs:
        try:
            task = state.resolve_task(ref.mode, ref.id)
        except Exception:  # noqa: BLE001 - a broken task is left out, not fatal
            continue
        built = [s for s in scenarios_for(ref.id, task) if misfit(task, sims.get(s, [])) is None]
        here = [state.source_spec] if misfit(task, current_parts) is None else []
        # on a simulated scene built for another task (its scripted user builds that one), the scenes built for
        # this task come first; on a camera or recording, the current source
        if state.source_spec in sims and state.source_spec not in built:
            specs = built + here
        else:
            specs = here + [s for s in built if s != state.source_spec]
        for spec in specs:
            out.append(
                m.ModeChoice(mode=ref.mode, task=ref.id, title=ref.title, source=spec,
                             switches_source=spec != state.source_spec)
            )
    return out


def suggestion(mode: str, task_id: str | None, task: Any) -> str:
    """What to choose instead when a task does not fit the current source."""
    specs = scenarios_for(task_id or "", task) if task is not None else []
    if specs:
        return f"choose it with the scene {' or '.join(specs)} (the panel's task list offers it)"
    return "choose a task that fits the current source, or another source"
