"""``/api/sessions``: the session list; start and pause (anyone), reset (teacher only)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header
from starlette.requests import HTTPConnection

from app import api_models as m
from app.routes.deps import Learner, State, require_teacher
from app.state import AppState
from app.storage import StorageError

router = APIRouter(tags=["sessions"])


def session_list(state: AppState) -> m.SessionsResponse:
    rows = state.storage.list_sessions()
    for r in rows:
        if r["id"] == state.session_id:
            r["frames"] = state.session_frames()
    return m.SessionsResponse(current=state.session_id, sessions=[m.SessionInfo(**r) for r in rows])


@router.get("/api/sessions", response_model=m.SessionsResponse)
def sessions(state: State) -> m.SessionsResponse:
    return session_list(state)


@router.post(
    "/api/sessions",
    response_model=m.SessionsResponse,
    dependencies=[Learner],
    responses={401: {"model": m.Message}, 403: {"model": m.Message}, 429: {"model": m.Message}},
)
def session_action(
    body: m.SessionAction,
    state: State,
    conn: HTTPConnection,
    x_teacher_password: Annotated[str | None, Header(max_length=1024)] = None,
    authorization: Annotated[str | None, Header(max_length=1024)] = None,
) -> m.SessionsResponse:
    """``start`` and ``pause`` hold or resume the stream; ``reset`` forgets placed parts and starts a new
    session, so it needs the teacher."""
    w = state.worker
    if body.action == "start":
        if state.session_id is None and not state.storage.read_only:
            state.start_session(w.start)
        else:
            w.start()
    elif body.action == "pause":
        w.pause()
    else:
        require_teacher(conn, state, x_teacher_password, authorization)

        def reset() -> None:
            state.user_poses.clear()
            w.reset()
            w.start()

        state.start_session(reset)  # the new session is stored first: a storage error changes nothing
    try:
        return session_list(state)
    except StorageError:  # the action is done; only the list cannot be read (/api/status tells why)
        return m.SessionsResponse(current=state.session_id, sessions=[])
