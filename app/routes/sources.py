"""``/api/sources``: the current frame source and switching it (teacher only)."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException

from app import api_models as m
from app.routes.deps import State, Teacher
from app.state import available_sources, safe_metadata

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
    responses={401: {"model": m.Message}, 403: {"model": m.Message}, 422: {"model": m.Message}},
)
def select_source(body: m.SourceSelect, state: State) -> m.SourcesResponse:
    """Switch the frame source (the teacher's control); the worker reopens and a new session starts."""
    kind = body.source.split(":", 1)[0]
    if kind not in ("sim", "recording", "camera"):
        raise HTTPException(422, f"source {body.source!r}: expected sim:<scenario>, recording:<dir> or camera:<n>")
    state.source_spec = body.source
    state.user_poses.clear()
    state.calibrations.clear()  # colour ranges belong to the old camera and light
    state.worker.reset()
    state.start_session()
    return sources(state)
