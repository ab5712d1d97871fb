"""``/api/modes``: the assembly mode, its task and — as one choice — the simulated scene it runs on (validated)."""

from __future__ import annotations

import logging
from typing import Annotated

from fastapi import APIRouter, Header, HTTPException
from pydantic import ValidationError
from starlette.requests import HTTPConnection

from app import api_models as m
from app.mode_choices import misfit, mode_choices, scenario_parts, suggestion
from app.routes.deps import Learner, State, on_worker, require_teacher
from app.state import AppState
from app.storage import StorageError
from tracker.pipeline import DEFAULT_TASKS

log = logging.getLogger(__name__)

router = APIRouter(tags=["modes"])


def task_refs(state: AppState) -> list[m.TaskRef]:
    """Every task a mode can use: the presets, then the teacher's sentence tasks."""
    refs: list[m.TaskRef] = []
    try:
        from tracker.assembly import list_presets

        for p in list_presets():
            refs.append(m.TaskRef(id=p["id"], title=p["title"], mode=p["mode"], origin="preset"))
    except Exception as exc:  # noqa: BLE001 - a broken preset must not hide the teacher tasks
        log.warning("task presets: %s", exc)
    try:
        stored = state.storage.list_tasks()
    except StorageError as exc:  # the presets still work; /api/status says what is wrong with the database
        log.warning("teacher tasks unavailable: %s", exc)
        stored = []
    for rec in stored:
        data = rec["data"]
        refs.append(
            m.TaskRef(
                id=f"teacher:{rec['id']}", title=str(data.get("source_sentence", "")), mode="learning", origin="teacher"
            )
        )
    return refs


def current_parts(state: AppState) -> list[str]:
    """Part names of the source in force (the pipeline's; a simulated scenario's before its first frame)."""
    pipeline = state.worker.pipeline
    if pipeline is not None:
        return [p.name for p in pipeline.parts]
    return scenario_parts().get(state.source_spec, [])


@router.get("/api/modes", response_model=m.ModesResponse)
def modes(state: State) -> m.ModesResponse:
    refs = task_refs(state)
    return m.ModesResponse(
        modes=["guidance", "guess", "learning", "none"],
        current=state.mode,
        task=state.task or DEFAULT_TASKS.get(state.mode),  # the task in force (a mode's default is named)
        source=state.source_spec,
        tasks=refs,
        choices=mode_choices(state, refs, current_parts(state)),
    )


@router.post(
    "/api/modes",
    response_model=m.ModesResponse,
    dependencies=[Learner],
    responses={401: {"model": m.Message}, 422: {"model": m.Message}, 429: {"model": m.Message}},
)
def select_mode(
    body: m.ModeSelect,
    state: State,
    conn: HTTPConnection,
    x_teacher_password: Annotated[str | None, Header(max_length=1024)] = None,
    authorization: Annotated[str | None, Header(max_length=1024)] = None,
) -> m.ModesResponse:
    """Switch the mode and its task; with ``source`` (a simulated scenario) switch the scene in the same step.

    Leaving a camera or recording for a simulated scene needs the teacher (it ends the class's live session);
    moving between simulated scenes does not. A task that does not fit the source is refused (422) with the
    choice that would fit."""
    try:
        task_obj = state.task_for_round(body.mode, state.resolve_task(body.mode, body.task))
    except (ValueError, ValidationError) as exc:
        raise HTTPException(422, str(exc)) from exc
    task_id = body.task or DEFAULT_TASKS.get(body.mode)
    if body.source is not None and body.source != state.source_spec:
        sims = scenario_parts()
        if body.source not in sims:
            raise HTTPException(422, f"source {body.source[:100]!r}: a mode switches only to a simulated scene "
                                f"({', '.join(sims)}); other sources are the teacher's (/api/sources)")
        if not state.source_spec.startswith("sim:"):
            require_teacher(conn, state, x_teacher_password, authorization)
        why = misfit(task_obj, sims[body.source])
        if why is not None:
            raise HTTPException(422, f"cannot run {task_id} on {body.source}: {why}; "
                                f"{suggestion(body.mode, task_id, task_obj)}")

        def switch() -> None:
            state.mode, state.task, state.source_spec = body.mode, body.task, body.source
            state.forget_scene()
            state.worker.reset()
            state.worker.start()

        # the new session is stored first: a storage error (503) changes nothing
        state.start_session(switch, source=body.source, mode_task=(body.mode, body.task))
        return modes(state)
    why = misfit(task_obj, current_parts(state))
    if why is not None:
        raise HTTPException(422, f"cannot switch to {body.mode} ({task_id}) on {state.source_spec}: {why}; "
                            f"{suggestion(body.mode, task_id, task_obj)}")
    mode = None if body.mode == "none" else body.mode

    def apply(pipeline, _frame):
        if pipeline is not None:
            try:
                pipeline.set_mode(mode, task_obj)
            except Exception as exc:  # noqa: BLE001 - e.g. the task does not fit the source's parts
                raise ValueError(f"cannot switch to {body.mode}: {exc}") from exc

    on_worker(state, apply)
    state.mode, state.task = body.mode, body.task
    return modes(state)
