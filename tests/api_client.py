"""Shared helpers of the HTTP API tests: a TestClient on a test source, and waiting for processed frames."""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator

from fastapi.testclient import TestClient

from app.server import create_app
from app.settings import Settings

TEST_HOST = "testserver"
"""The Host of TestClient requests (allowed in :func:`app_settings`)."""
LOCAL_CLIENT = ("127.0.0.1", 50000)
"""TestClient requests come from this address: the server machine itself, as a local browser would."""


def app_settings(tmp_path, **settings) -> Settings:
    """Settings for a test app: database under ``tmp_path``, viser off, no mode, 20 particles, TestClient's host
    allowed; ``settings`` override any of these."""
    base = {
        "database": str(tmp_path / "agent.sqlite3"),
        "viser_port": 0,
        "mode": "none",
        "n_particles": 20,
        "allowed_hosts": [TEST_HOST],
    }
    return Settings(**{**base, **settings})


def local_client(app, **kwargs) -> TestClient:
    """A TestClient whose requests come from the loopback address (as a browser on the server machine)."""
    return TestClient(app, client=LOCAL_CLIENT, **kwargs)


@contextlib.contextmanager
def app_client(tmp_path, open_source: Callable, **settings) -> Iterator[TestClient]:
    """The web app on :func:`app_settings`, frames from ``open_source(spec)``, requests from loopback."""
    app = create_app(app_settings(tmp_path, **settings), open_source=open_source)
    with local_client(app) as client:
        yield client


def wait_frames(client: TestClient, n: int = 3, timeout: float = 240.0) -> dict:
    """Wait until the worker has processed frame ``n``; returns /api/status (AssertionError on timeout; generous:
    the first test of a run pays the JIT compilation of the tracker's numba kernels on a fresh clone, which takes
    minutes on a loaded machine)."""
    t0 = time.time()
    while time.time() - t0 < timeout:
        st = client.get("/api/status").json()
        if (st["worker"]["frame_index"] or 0) >= n:
            return st
        time.sleep(0.05)
    raise AssertionError(f"no frames: {client.get('/api/status').json()}")
