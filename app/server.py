"""The FastAPI application: the panel (``/``), the teacher editor (``/teacher``), REST API and the ``/ws`` stream.

``create_app(settings)`` builds the shared :class:`app.state.AppState` (storage, teacher auth, the pipeline
worker thread, the viser scene) and mounts one router per resource from :mod:`app.routes`; the worker
starts with the app (lifespan) and every endpoint only reads its latest snapshot or queues a command for it,
so HTTP handling never waits for a frame to be processed.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable
from typing import Any

from fastapi import Depends, FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.staticfiles import StaticFiles

from app.middleware import LOOPBACK_NAMES, BodyLimit, HostGuard, SecurityHeaders, panel_csp
from app.routes import auth, modes, pages, parts, results, sessions, sources, status, tasks, ws
from app.routes.deps import api_limit
from app.settings import Settings
from app.state import WEB_DIR, AppState, open_source_spec, version
from app.storage import StorageError
from tracker.sources.base import FrameSource

__all__ = ["AppState", "create_app", "open_source_spec"]

log = logging.getLogger(__name__)

API_ROUTERS = (status, sources, modes, sessions, parts, auth, tasks, results)
"""Router modules of ``/api``, each with a ``router`` for one resource (requests count against ``api_rate``)."""
OTHER_ROUTERS = (pages, ws)


def trusted_hosts(settings: Settings) -> list[str]:
    """Host names the server answers to: loopback names, ``--host`` (unless a wildcard address), ``allowed_hosts``."""
    hosts = [*LOOPBACK_NAMES, *settings.allowed_hosts]
    if settings.host not in ("0.0.0.0", "::", ""):
        hosts.append(settings.host)
    return hosts


def friendly(err: dict[str, Any]) -> str:
    """A plain-language version of a pydantic error message (for forms)."""
    kind, ctx, msg = err.get("type", ""), err.get("ctx") or {}, str(err.get("msg", ""))
    if kind == "string_too_short" and ctx.get("min_length") == 1:
        return "must not be empty"
    if kind == "too_short" and "min_length" in ctx:
        n = ctx["min_length"]
        what = "words" if err.get("loc", [None, None])[-1] == "words" else "items"
        return f"give at least {n} {what}"
    if kind == "missing":
        return "is required"
    if kind == "extra_forbidden":
        return "is not a known field"
    return msg.removeprefix("Value error, ")


async def validation_error(_request: Request, exc: RequestValidationError) -> JSONResponse:
    """422 with FastAPI's usual ``detail`` list (loc, msg, type), messages in plain language."""
    detail = [{"loc": list(e.get("loc", [])), "msg": friendly(e), "type": e.get("type", "")} for e in exc.errors()]
    return JSONResponse({"detail": detail}, status_code=422)


async def storage_error(_request: Request, exc: StorageError) -> JSONResponse:
    """503 with the storage's message (it names the file and what to do); the change was not applied."""
    log.error("%s", exc)
    return JSONResponse({"detail": f"{exc} (nothing was changed)"}, status_code=503)


def create_app(settings: Settings | None = None, open_source: Callable[[str], FrameSource] | None = None) -> FastAPI:
    """The web application. ``open_source(spec)`` replaces the source registry (tests use it)."""
    settings = settings or Settings()
    state = AppState(settings, open_source)

    @contextlib.asynccontextmanager
    async def lifespan(_app: FastAPI):
        state.startup()
        try:
            yield
        finally:
            state.shutdown()

    app = FastAPI(
        title="Assembly Agent",
        version=version(),
        description="Tracks coloured parts on a table and guides the user (guidance, guess and learning modes). "
        "Live state streams on the /ws websocket (one JSON snapshot per processed frame).",
        lifespan=lifespan,
    )
    app.state.assembly = state
    app.add_exception_handler(RequestValidationError, validation_error)
    app.add_exception_handler(StorageError, storage_error)
    app.mount("/static", StaticFiles(directory=WEB_DIR / "static"), name="static")
    for module in API_ROUTERS:
        app.include_router(module.router, dependencies=[Depends(api_limit)])
    for module in OTHER_ROUTERS:
        app.include_router(module.router)
    # the last added is the outermost: headers on every answer, then Host/Origin, then the body limit
    app.add_middleware(BodyLimit, max_bytes=settings.max_body_bytes)
    app.add_middleware(HostGuard, hosts=trusted_hosts(settings), origins=settings.allowed_origins)
    app.add_middleware(SecurityHeaders, csp=panel_csp(settings.viser_port))
    return app
