"""Dependencies shared by the routers: the app state, settings, storage, the teacher session, worker commands.

Every router reaches the shared :class:`app.state.AppState` through :func:`get_state` (it lives on
``app.state.assembly``), so a router module holds no global state and tests can build several apps.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Annotated, Any

from fastapi import Depends, Header, HTTPException
from starlette.requests import HTTPConnection

from app.limits import retry_after
from app.settings import Settings
from app.state import COMMAND_TIMEOUT_S, AppState
from app.storage import Storage


def get_state(conn: HTTPConnection) -> AppState:
    """The application's shared state (HTTP requests and websockets alike)."""
    return conn.app.state.assembly


State = Annotated[AppState, Depends(get_state)]


def get_settings(state: State) -> Settings:
    return state.settings


def get_storage(state: State) -> Storage:
    return state.storage


SettingsDep = Annotated[Settings, Depends(get_settings)]
StorageDep = Annotated[Storage, Depends(get_storage)]


def client_key(conn: HTTPConnection) -> str:
    """The key of a client for rate limits: its address."""
    return conn.client.host if conn.client is not None else "unknown"


def too_many(wait_s: float, what: str) -> HTTPException:
    """A 429 saying when to try again (``Retry-After``, whole seconds)."""
    after = retry_after(wait_s)
    return HTTPException(429, f"too many {what}; try again in {after} s", headers={"Retry-After": after})


def api_limit(conn: HTTPConnection, state: State) -> None:
    """Every API request counts against the client's ``api_rate``."""
    wait = state.limits.api.take(client_key(conn))
    if wait is not None:
        raise too_many(wait, "requests")


def learner_limit(conn: HTTPConnection, state: State) -> None:
    """Actions that make the pipeline work (mode, boxes, auto-place, start/pause) count against ``learner_rate``."""
    wait = state.limits.learner.take(client_key(conn))
    if wait is not None:
        raise too_many(wait, "actions")


ApiLimit = Depends(api_limit)
Learner = Depends(learner_limit)


def check_password_throttled(conn: HTTPConnection, state: AppState, password: str) -> bool:
    """Whether ``password`` is the teacher's; a client that guessed wrong too often gets a 429 before hashing."""
    client = client_key(conn)
    wait = state.limits.login.reserve(client)
    if wait is not None:
        raise too_many(wait, "wrong teacher passwords")
    ok = state.auth.check_password(password)
    if ok:
        state.limits.login.succeeded(client)
    return ok


def teacher_token(conn: HTTPConnection, authorization: str | None) -> str | None:
    """The session token of a request: ``Authorization: Bearer <token>``, else the ``teacher_token`` cookie."""
    if authorization and authorization.lower().startswith("bearer "):
        return authorization[7:].strip()
    return conn.cookies.get("teacher_token")


def require_teacher(
    conn: HTTPConnection,
    state: State,
    x_teacher_password: Annotated[str | None, Header(max_length=1024)] = None,
    authorization: Annotated[str | None, Header(max_length=1024)] = None,
) -> None:
    """Editing requires the teacher password (header), a login token (cookie) or ``Bearer <token>``."""
    if not state.auth.is_configured:
        raise HTTPException(403, "no teacher password is set yet: set one on the /teacher page first")
    if state.auth.check_token(teacher_token(conn, authorization)):
        return
    if x_teacher_password and check_password_throttled(conn, state, x_teacher_password):
        return
    raise HTTPException(401, "this needs the teacher: log in on the /teacher page (wrong or missing teacher password)")


Teacher = Depends(require_teacher)


def on_worker(state: AppState, apply: Callable[[Any, Any], Any]) -> Any:
    """Run ``apply(pipeline, latest frame)`` on the worker thread and return its result; a busy worker is a 503,
    a LookupError (nothing to act on yet) a 409, a ValueError (bad request) a 422."""
    try:
        return state.worker.submit(apply).result(timeout=COMMAND_TIMEOUT_S)
    except FutureTimeout as exc:
        raise HTTPException(503, "the pipeline is busy; try again") from exc
    except LookupError as exc:
        raise HTTPException(409, str(exc)) from exc
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from exc
