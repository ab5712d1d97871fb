"""Shared helpers of the HTTP API tests: a TestClient on a test source, and waiting for processed frames."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator

from fastapi.testclient import TestClient

from app.server import create_app
from app.settings import Settings


@contextlib.contextmanager
def app_client(tmp_path, open_source: Callable, **settings) -> Iterator[TestClient]:
    """The web app with its database under ``tmp_path``, viser off, no mode, 20 particles, frames from
    ``open_source(spec)``; ``settings`` override any of these."""
    base = {"database": str(tmp_path / "agent.sqlite3"), "viser_port": 0, "mode": "none", "n_particles": 20}
    app = create_app(Settings(**{**base, **settings}), open_source=open_source)
    with TestClient(app) as client:
        yield client


def wait_frames(client: TestClient, n: int = 3, timeout: float = 20.0) -> dict:
    """Wait until the worker has processed frame ``n``; returns /api/status (AssertionError on timeout)."""
    t0 = time.time()
    while time.time() - t0 < timeout:
        st = client.get("/api/status").json()
        if (st["worker"]["frame_index"] or 0) >= n:
            return st
        time.sleep(0.05)
    raise AssertionError(f"no frames: {client.get('/api/status').json()}")
