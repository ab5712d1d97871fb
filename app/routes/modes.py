"""``/api/modes``: the assembly mode and its task (a learner's choice, validated)."""

from __future__ import annotations

import logging

from fastapi import APIRouter, HTTPException
from pydantic import ValidationError

from app import api_models as m
from app.routes.deps import Learner, State, on_worker
from app.state import AppState

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
    for rec in state.storage.list_tasks():
        data = rec["data"]
        refs.append(
            m.TaskRef(
                id=f"teacher:{rec['id']}", title=str(data.get("source_sentence", "")), mode="learning", origin="teacher"
            )
        )
    return refs


@router.get("/api/modes", response_model=m.ModesResponse)
def modes(state: State) -> m.ModesResponse:
    return m.ModesResponse(
        modes=["guidance", "guess", "learning", "none"], current=state.mode, task=state.task, tasks=task_refs(state)
    )


@router.post(
    "/api/modes",
    response_model=m.ModesResponse,
    dependencies=[Learner],
    responses={422: {"model": m.Message}, 429: {"model": m.Message}},
)
def select_mode(body: m.ModeSelect, state: State) -> m.ModesResponse:
    try:
        task_obj = state.task_for_round(body.mode, state.resolve_task(body.mode, body.task))
    except (ValueError, ValidationError) as exc:
        raise HTTPException(422, str(exc)) from exc
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
