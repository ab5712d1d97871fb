"""The /ws websocket pushes each snapshot as soon as the worker publishes it, JSON-encoded once for all clients.

The source is gated: a frame exists only when the test lets one through, so a message for frame k can
only come from the push that followed frame k's publication (no later frame, no timer needed).
"""

from __future__ import annotations

import json
import queue
import threading
import time

import pytest
from api_client import app_settings, local_client
from test_worker import SyntheticTable

from app.server import create_app
from app.settings import Settings
from tracker.frame import Frame

PUSH_BOUND_S = 3.0
"""Generous bound for one push (the handler's fallback wake-up is 5 s, so a timer could not meet it)."""


class GatedTable(SyntheticTable):
    """Yields frame i only after ``gate.release()``."""

    def __init__(self):
        super().__init__(n_frames=100_000)
        self.gate = threading.Semaphore(0)

    def _frames(self):
        for i in range(self.n_frames):
            while not self.gate.acquire(timeout=0.2):
                if self.closed:
                    return
            yield Frame(i, i / 30.0, self.color.copy(), self.depth.copy(), self.intrinsics)


@pytest.fixture()
def gated(tmp_path):
    src = GatedTable()
    app = create_app(app_settings(tmp_path, source="synthetic:"), open_source=lambda spec: src)
    with local_client(app) as client:
        yield client, src, app.state.assembly.worker


def receive(ws, timeout: float) -> tuple[str, float]:
    """The next text message and when it came; fails after ``timeout`` seconds."""
    out: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: out.put(ws.receive_text()), daemon=True).start()
    try:
        text = out.get(timeout=timeout)
    except queue.Empty:
        pytest.fail(f"no websocket message within {timeout} s")
    return text, time.monotonic()


def test_websocket_pushes_each_published_snapshot(gated):
    client, src, worker = gated
    published: dict[int, float] = {}
    worker.add_listener(lambda s: published.setdefault(s.frame_index, time.monotonic()))
    with client.websocket_connect("/ws") as ws:
        src.gate.release()
        text, _ = receive(ws, 20.0)  # frame 0 (start-up of the worker and pipeline)
        assert json.loads(text)["frame_index"] == 0
        for k in range(1, 4):
            src.gate.release()  # exactly one more frame exists
            text, got = receive(ws, 20.0)
            assert json.loads(text)["frame_index"] == k
            assert got - published[k] < PUSH_BOUND_S


def test_snapshot_json_is_encoded_once_for_all_clients(gated):
    client, src, worker = gated
    with client.websocket_connect("/ws") as a, client.websocket_connect("/ws") as b:
        src.gate.release()
        text_a, _ = receive(a, 20.0)
        text_b, _ = receive(b, 20.0)
    assert text_a == text_b
    first = worker.snapshot_json()
    assert first is worker.snapshot_json()  # cached per snapshot version, not re-encoded
    assert first[1] == text_a
    d = json.loads(text_a)
    assert d["worker"]["state"] in ("running", "starting") and "particles" not in d


def test_simulator_runs_in_a_child_process_kept_until_the_source_changes(tmp_path):
    app = create_app(app_settings(tmp_path, source="sim:static"))  # the real registry: a child process renders
    state = app.state.assembly
    with local_client(app) as client:
        t0 = time.time()
        while (client.get("/api/status").json()["worker"]["frame_index"] or 0) < 2:
            assert time.time() - t0 < 120, client.get("/api/status").json()
            time.sleep(0.1)
        t0 = time.time()  # the looping simulator's source is closed and reopened (a view of the same process)
        while (meta := client.get("/api/sources").json()["metadata"]) == {}:  # between the two there is none
            assert time.time() - t0 < 30
            time.sleep(0.05)
        assert meta["process"] == "child"
        first = state._process_source[1]
        assert first.alive
        assert client.post("/api/sources", json={"source": "sim:free"}).status_code == 403  # teacher only
        client.post("/api/auth/setup", json={"password": "teacher-password"})
        assert client.post("/api/sources", json={"source": "sim:free"}).status_code == 200
        t0 = time.time()
        while state._process_source is None or state._process_source[0] != "sim:free":
            assert time.time() - t0 < 120
            time.sleep(0.1)
        assert not first.alive  # the old scenario's process was closed
    assert state._process_source is None  # and the last one at shutdown


def test_server_default_particle_count(tmp_path):
    """N = 100 with the default preset; a named tracker config keeps its own N unless N is given too."""
    from app.server import AppState

    def n_of(**kw):
        state = AppState(Settings(database=str(tmp_path / "n.db"), viser_port=0, mode="none", **kw))
        src = SyntheticTable(n_frames=1)
        return state._make_pipeline(src).tracker.config.n_particles

    assert n_of() == 100
    assert n_of(tracker_config="seed-exp1") == 225
    assert n_of(tracker_config="seed-exp1", n_particles=60) == 60


class NumberedTable(GatedTable):
    """A gated table whose frame i carries its number in a corner patch of the colour image (grey level 20 i)."""

    def _frames(self):
        for frame in super()._frames():
            frame.color[:16, :16] = min(255, 20 * frame.index)
            yield frame


def test_panel_websocket_sends_each_snapshot_with_the_jpeg_of_its_frame(tmp_path):
    """``/ws?image=1``: the snapshot's JSON, then the JPEG of the same frame (the panel shows them together)."""
    import cv2
    import numpy as np

    src = NumberedTable()
    app = create_app(app_settings(tmp_path, source="synthetic:"), open_source=lambda spec: src)
    with local_client(app) as client, client.websocket_connect("/ws?image=1") as ws:
        for k in range(4):
            src.gate.release()  # exactly one more frame exists
            text, _ = receive(ws, 20.0)
            snap = json.loads(text)
            jpeg = ws.receive_bytes()
            image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
            assert snap["frame_index"] == k
            assert [image.shape[1], image.shape[0]] == snap["image_size"]
            assert abs(float(image[2:14, 2:14].mean()) - 20 * k) < 6  # the image of frame k, not another one
        with client.websocket_connect("/ws") as plain:  # other clients: snapshots only (text messages)
            assert json.loads(receive(plain, 20.0)[0])["frame_index"] == 3  # the newest one at once
            src.gate.release()
            assert json.loads(receive(plain, 20.0)[0])["frame_index"] == 4  # no image between them
