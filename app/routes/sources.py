"""``/api/sources``: the current frame source and switching it (teacher only)."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException

from app import api_models as m
from app.routes.deps import SettingsDep, State, Teacher
from app.state import available_sources, safe_metadata
from app.validation import check_source_spec

router = APIRouter(tags=["sources"])


@router.get("/api/sources", response_model=m.SourcesResponse)
def sources(state: State) -> m.SourcesResponse:
    src = state.worker.source
    return m.SourcesResponse(
        current=state.source_spec, metadata=safe_metadata(src) if src else {}, available=available_sources()
    )


@router.post(
    "/api/sources",
    response_model=m.SourcesResponse,
    dependencies=[Teacher],
    responses={
        401: {"model": m.Message},
        403: {"model": m.Message},
        422: {"model": m.Message},
        503: {"model": m.Message},
    },
)
def select_source(body: m.SourceSelect, state: State, settings: SettingsDep) -> m.SourcesResponse:
    """Switch the frame source (the teacher's control); the worker reopens and a new session starts.

    A simulated scenario must exist, a camera is given by device numbers, and a recording must lie inside one of
    the data folders of ``settings.recording_dirs`` (422 otherwise)."""
    scenarios = [s.spec.split(":", 1)[1] for s in available_sources() if s.kind == "sim"]
    try:
        spec = check_source_spec(body.source, scenarios, settings.recording_dirs)
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from exc

    def switch() -> None:
        state.source_spec = spec
        state.forget_scene()
        state.worker.reset()

    state.start_session(switch, source=spec)  # the new session is stored first: a storage error changes nothing
    return sources(state)
