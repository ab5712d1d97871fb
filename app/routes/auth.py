"""``/api/auth``: the teacher password (first setup, login, logout) and the session cookie.

Wrong passwords are throttled per client and server-wide (429 with ``Retry-After``, see :mod:`app.limits`);
the first password can only be set from the server machine itself (loopback), unless it comes from the
environment (``ASSEMBLY_AGENT_TEACHER_PASSWORD``), in which case no setup is needed at all.
"""

from __future__ import annotations

import ipaddress

from fastapi import APIRouter, HTTPException, Request, Response

from app import api_models as m
from app.routes.deps import State, check_password_throttled, client_key

router = APIRouter(tags=["teacher"])


def set_token_cookie(response: Response, token: str) -> None:
    response.set_cookie("teacher_token", token, httponly=True, samesite="strict")


def is_loopback(host: str) -> bool:
    """Whether the client address ``host`` is this machine (127.0.0.0/8, ::1)."""
    try:
        return ipaddress.ip_address(host.split("%", 1)[0]).is_loopback
    except ValueError:
        return False


@router.get("/api/auth", response_model=m.AuthStatus)
def auth_status(request: Request, state: State) -> m.AuthStatus:
    return m.AuthStatus(
        configured=state.auth.is_configured, logged_in=state.auth.check_token(request.cookies.get("teacher_token"))
    )


@router.post(
    "/api/auth/setup",
    response_model=m.AuthStatus,
    responses={403: {"model": m.Message}, 422: {"model": m.Message}, 429: {"model": m.Message}},
)
def auth_setup(body: m.PasswordBody, request: Request, response: Response, state: State) -> m.AuthStatus:
    """Set the first teacher password (from this machine only) and log in."""
    if state.auth.is_configured:
        raise HTTPException(403, "a teacher password is already set")
    if not is_loopback(client_key(request)):
        raise HTTPException(
            403,
            "the first teacher password can only be set on the server machine itself (open /teacher on "
            "http://127.0.0.1) or with ASSEMBLY_AGENT_TEACHER_PASSWORD",
        )
    try:
        state.auth.setup(body.password)
    except PermissionError as exc:
        raise HTTPException(403, str(exc)) from exc
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from exc
    set_token_cookie(response, state.auth.new_token())
    return m.AuthStatus(configured=True, logged_in=True)


@router.post(
    "/api/auth/login",
    response_model=m.AuthStatus,
    responses={401: {"model": m.Message}, 403: {"model": m.Message}, 429: {"model": m.Message}},
)
def auth_login(body: m.PasswordBody, request: Request, response: Response, state: State) -> m.AuthStatus:
    if not state.auth.is_configured:
        raise HTTPException(403, "no teacher password is set yet")
    if not check_password_throttled(request, state, body.password):
        raise HTTPException(401, "wrong teacher password")
    set_token_cookie(response, state.auth.new_token())
    return m.AuthStatus(configured=True, logged_in=True)


@router.post("/api/auth/logout", response_model=m.AuthStatus)
def auth_logout(request: Request, response: Response, state: State) -> m.AuthStatus:
    state.auth.logout(request.cookies.get("teacher_token"))
    response.delete_cookie("teacher_token")
    return m.AuthStatus(configured=state.auth.is_configured, logged_in=False)
