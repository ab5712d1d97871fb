"""``/api/auth``: the teacher password (first setup, login, logout) and the session cookie."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Request, Response

from app import api_models as m
from app.routes.deps import State

router = APIRouter(tags=["teacher"])


def set_token_cookie(response: Response, token: str) -> None:
    response.set_cookie("teacher_token", token, httponly=True, samesite="strict")


@router.get("/api/auth", response_model=m.AuthStatus)
def auth_status(request: Request, state: State) -> m.AuthStatus:
    return m.AuthStatus(
        configured=state.auth.is_configured, logged_in=state.auth.check_token(request.cookies.get("teacher_token"))
    )


@router.post(
    "/api/auth/setup", response_model=m.AuthStatus, responses={403: {"model": m.Message}, 422: {"model": m.Message}}
)
def auth_setup(body: m.PasswordBody, response: Response, state: State) -> m.AuthStatus:
    try:
        state.auth.setup(body.password)
    except PermissionError as exc:
        raise HTTPException(403, str(exc)) from exc
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from exc
    set_token_cookie(response, state.auth.login(body.password) or "")
    return m.AuthStatus(configured=True, logged_in=True)


@router.post(
    "/api/auth/login", response_model=m.AuthStatus, responses={401: {"model": m.Message}, 403: {"model": m.Message}}
)
def auth_login(body: m.PasswordBody, response: Response, state: State) -> m.AuthStatus:
    if not state.auth.is_configured:
        raise HTTPException(403, "no teacher password is set yet")
    token = state.auth.login(body.password)
    if token is None:
        raise HTTPException(401, "wrong teacher password")
    set_token_cookie(response, token)
    return m.AuthStatus(configured=True, logged_in=True)


@router.post("/api/auth/logout", response_model=m.AuthStatus)
def auth_logout(request: Request, response: Response, state: State) -> m.AuthStatus:
    state.auth.logout(request.cookies.get("teacher_token"))
    response.delete_cookie("teacher_token")
    return m.AuthStatus(configured=state.auth.is_configured, logged_in=False)
