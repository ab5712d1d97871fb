"""ASGI middleware of the web app: request body limit, Host/Origin checks and security headers.

* :class:`BodyLimit`: a body larger than ``max_bytes`` is answered ``413`` before the app reads it (by its
  ``Content-Length``, or while it streams in without one), so a huge upload costs no memory.
* :class:`HostGuard`: the ``Host`` header must name this server (a DNS-rebinding page cannot talk to it), and
  a browser's ``Origin`` must be an allowed page for the ``/ws`` stream and for every state-changing request
  (another site cannot drive the panel). Requests without ``Origin`` (curl, scripts) pass the Origin check.
* :class:`SecurityHeaders`: ``Content-Security-Policy`` (own scripts, styles and connections only; the viser
  scene may be framed from its port; the pages may not be framed), ``X-Content-Type-Options: nosniff``,
  ``Referrer-Policy: no-referrer`` and ``X-Frame-Options: DENY`` on every response.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable
from urllib.parse import urlsplit

from starlette.types import ASGIApp, Message, Receive, Scope, Send

SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")


async def send_json(send: Send, status: int, detail: str, headers: Iterable[tuple[bytes, bytes]] = ()) -> None:
    """A complete JSON ``{"detail": ...}`` response."""
    body = json.dumps({"detail": detail}).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()), *headers],
        }
    )
    await send({"type": "http.response.body", "body": body})


def header(scope: Scope, name: bytes) -> str | None:
    for key, value in scope.get("headers", ()):
        if key == name:
            return value.decode("latin-1")
    return None


class BodyLimit:
    """``413`` for request bodies above ``max_bytes`` (see the module docstring)."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = int(max_bytes)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] in SAFE_METHODS:
            await self.app(scope, receive, send)
            return
        too_big = f"request body too large: at most {self.max_bytes} bytes"
        length = header(scope, b"content-length")
        if length is not None and (not length.strip().isdigit() or int(length) > self.max_bytes):
            await send_json(send, 413, too_big)
            return
        # read the body here (bounded), then hand it to the app as one message
        chunks, size = [], 0
        while True:
            message = await receive()
            if message["type"] != "http.request":
                return  # the client left
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > self.max_bytes:
                await send_json(send, 413, too_big)
                return
            chunks.append(chunk)
            if not message.get("more_body", False):
                break
        replayed = False

        async def replay() -> Message:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": b"".join(chunks), "more_body": False}
            return await receive()

        await self.app(scope, replay, send)


def split_host(value: str) -> str:
    """The host name of a ``Host`` header value (``name``, ``name:port``, ``[v6]:port``), lower case."""
    value = value.strip().lower()
    if value.startswith("["):
        return value[1 : value.find("]")] if "]" in value else value
    return value.rsplit(":", 1)[0] if value.count(":") == 1 else value


class HostGuard:
    """Host and Origin checks (see the module docstring); ``'*'`` in ``hosts`` turns the Host check off."""

    def __init__(self, app: ASGIApp, hosts: Iterable[str], origins: Iterable[str] = ()) -> None:
        self.app = app
        self.hosts = {split_host(h) for h in hosts}
        self.any_host = "*" in self.hosts
        self.origins = {o.strip().lower().rstrip("/") for o in origins}

    def host_ok(self, host: str | None) -> bool:
        return self.any_host or (host is not None and split_host(host) in self.hosts)

    def origin_ok(self, origin: str | None, host: str | None) -> bool:
        if origin is None:
            return True  # not a browser page (curl, scripts, tests)
        origin = origin.strip().lower().rstrip("/")
        if origin in self.origins:
            return True
        parts = urlsplit(origin)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            return False
        if self.any_host:  # any host allowed: the page must come from the host it talks to
            return host is not None and split_host(host) == parts.hostname
        return parts.hostname in self.hosts

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        host = header(scope, b"host")
        if not self.host_ok(host):
            await self.refuse(scope, receive, send, 400, "host not allowed: start the server with --allowed-host NAME")
            return
        unsafe = scope["type"] == "websocket" or scope["method"] not in SAFE_METHODS
        if unsafe and not self.origin_ok(header(scope, b"origin"), host):
            await self.refuse(scope, receive, send, 403, "origin not allowed: only this server's own pages may do this")
            return
        await self.app(scope, receive, send)

    @staticmethod
    async def refuse(scope: Scope, receive: Receive, send: Send, status: int, detail: str) -> None:
        """A JSON error, or for a websocket a refused handshake (close code 1008, policy violation)."""
        if scope["type"] == "websocket":
            await receive()  # websocket.connect
            await send({"type": "websocket.close", "code": 1008, "reason": detail[:120]})
        else:
            await send_json(send, status, detail)


class SecurityHeaders:
    """Security headers on every HTTP response; ``csp(scope)`` gives the Content-Security-Policy of a request."""

    def __init__(self, app: ASGIApp, csp: Callable[[Scope], str]) -> None:
        self.app = app
        self.csp = csp

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        policy = self.csp(scope).encode()

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = [h for h in message.get("headers", ()) if h[0] != b"content-security-policy"]
                headers += [
                    (b"content-security-policy", policy),
                    (b"x-content-type-options", b"nosniff"),
                    (b"referrer-policy", b"no-referrer"),
                    (b"x-frame-options", b"DENY"),
                ]
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, send_with_headers)


def panel_csp(viser_port: int | None) -> Callable[[Scope], str]:
    """The pages' policy: everything from this server; the viser scene framed from ``viser_port`` of the same
    host name the page was loaded from (on a loopback name also of the other one: the panel frames the scene from
    there so that the browser draws it in a process of its own); the API docs (``/docs``, ``/redoc``) may load
    FastAPI's CDN files."""

    def csp(scope: Scope) -> str:
        path = scope.get("path", "")
        if path in ("/docs", "/redoc", "/docs/oauth2-redirect"):
            return "frame-ancestors 'none'"  # FastAPI's documentation pages load scripts from a CDN
        frame = "'none'"
        host = split_host(header(scope, b"host") or "")
        if viser_port and host:
            names = [f"[{host}]" if ":" in host else host]
            if host in LOOPBACK_NAMES:  # the panel frames the scene from the other loopback name (own process)
                names += [n for n in ("127.0.0.1", "localhost") if n != host]
            frame = " ".join(f"{scheme}://{n}:{viser_port}" for n in names for scheme in ("http", "https"))
        return (
            "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; "
            f"connect-src 'self'; frame-src {frame}; object-src 'none'; base-uri 'none'; form-action 'self'; "
            "frame-ancestors 'none'"
        )

    return csp
