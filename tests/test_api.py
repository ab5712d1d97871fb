"""HTTP API and websocket of the web app, on the synthetic test table (FastAPI TestClient)."""

from __future__ import annotations

import time

import pytest
from api_client import app_client, wait_frames
from test_worker import SyntheticTable

PASSWORD = "profesora-1"
TASK = {"source_sentence": "Μου αρέσει ο καφές", "words": ["Me", "gusta", "el", "café"], "distractors": ["leche"]}


@pytest.fixture()
def client(tmp_path):
    with app_client(tmp_path, lambda spec: SyntheticTable(n_frames=100_000), source="synthetic:", max_fps=100) as c:
        yield c


def test_status_and_sources(client):
    st = wait_frames(client)
    assert st["worker"]["state"] == "running"
    assert st["parts"] == ["red", "green"]
    assert st["viser_port"] is None
    src = client.get("/api/sources").json()
    assert src["current"] == "synthetic:"
    assert src["metadata"]["name"] == "synthetic"
    assert any(s["kind"] == "camera" for s in src["available"])


def test_openapi_is_complete(client):
    schema = client.get("/openapi.json").json()
    paths = schema["paths"]
    for path in (
        "/api/status",
        "/api/sources",
        "/api/modes",
        "/api/sessions",
        "/api/tasks",
        "/api/tasks/{task_id}",
        "/api/boxes",
        "/api/frame.jpg",
        "/api/auth/login",
    ):
        assert path in paths, path
    for verb in ("get", "put", "delete"):
        assert verb in paths["/api/tasks/{task_id}"]
    # every JSON endpoint documents its 200/201 response body with a schema
    for path, ops in paths.items():
        for verb, op in ops.items():
            ok = op["responses"].get("200") or op["responses"].get("201")
            assert ok is not None, (verb, path)
            if path not in ("/api/frame.jpg", "/api/results.csv"):
                assert "$ref" in str(ok["content"]["application/json"]["schema"]), (verb, path)
    assert "SentenceTask" in schema["components"]["schemas"]


def test_websocket_streams_increasing_frames(client):
    wait_frames(client, 1)
    with client.websocket_connect("/ws") as ws:
        msgs = [ws.receive_json() for _ in range(4)]
    idx = [m["frame_index"] for m in msgs]
    assert idx == sorted(idx) and len(set(idx)) == 4
    m = msgs[-1]
    for key in ("time", "poses", "connections", "mode_state", "instruction", "fps", "detections", "boxes"):
        assert key in m
    assert set(m["poses"]) == {"red", "green"}
    assert len(m["poses"]["red"]["q"]) == 4
    assert m["detections"]["red"]["bbox"] is not None


def test_frame_jpeg(client):
    wait_frames(client, 1)
    r = client.get("/api/frame.jpg")
    assert r.status_code == 200 and r.headers["content-type"] == "image/jpeg"
    assert r.content[:2] == b"\xff\xd8"
    assert int(r.headers["x-frame-index"]) >= 1


def test_drawn_box_places_part_on_table(client):
    wait_frames(client, 2)
    # the red square of the synthetic table is at (40..49, 60..69) in the 160x120 image
    r = client.post("/api/boxes", json={"x": 38, "y": 58, "w": 14, "h": 14})
    assert r.status_code == 200, r.text
    box = r.json()
    assert box["part"] == "red"  # chosen by colour
    t = box["pose"]["t"]
    assert 0.5 < t[2] < 1.2  # on the table, in front of the camera
    r = client.post("/api/boxes", json={"x": 81, "y": 61, "w": 8, "h": 8, "part": "green", "action": "calibrate"})
    assert r.status_code == 200 and r.json()["part"] == "green" and r.json()["pose"] is None
    r = client.post("/api/boxes", json={"x": 10, "y": 10, "w": 5, "h": 5, "part": "violet"})
    assert r.status_code == 422 and "unknown part" in r.json()["detail"]
    r = client.post("/api/boxes", json={"x": 10, "y": 10, "w": 0, "h": 5})
    assert r.status_code == 422


def test_box_without_part_is_refused_and_calibration_undone(client):
    wait_frames(client, 2)
    # a box over bare (flat, grey) table: no part's colour, nothing standing there
    r = client.post("/api/boxes", json={"x": 100, "y": 20, "w": 20, "h": 20})
    assert r.status_code == 422 and "no part in the box" in r.json()["detail"]
    r = client.post("/api/boxes", json={"x": 100, "y": 20, "w": 20, "h": 20, "part": "red"})
    assert r.status_code == 422 and "no red part in the box" in r.json()["detail"]
    # learning "green" from table pixels would make the whole table green
    r = client.post("/api/boxes", json={"x": 100, "y": 20, "w": 20, "h": 20, "part": "green", "action": "calibrate"})
    assert r.status_code == 422 and "covers" in r.json()["detail"] and "of the image" in r.json()["detail"]
    assert client.get("/api/calibration").json()["calibrations"] == []
    assert client.get("/api/boxes").json()["boxes"] == []  # nothing refused was kept
    # a real calibration (the red square learnt as "green") is in force, then undone
    r = client.post("/api/boxes", json={"x": 41, "y": 61, "w": 8, "h": 8, "part": "green", "action": "calibrate"})
    assert r.status_code == 200, r.text
    assert [c["part"] for c in client.get("/api/calibration").json()["calibrations"]] == ["green"]
    n = wait_frames(client, 0)["worker"]["frame_index"]
    wait_frames(client, n + 2)
    assert client.get("/api/snapshot").json()["detections"]["green"]["bbox"][0] == 40  # now found on the red square
    r = client.post("/api/calibration/undo")
    assert r.status_code == 200 and r.json()["calibrations"] == []
    n = wait_frames(client, 0)["worker"]["frame_index"]
    wait_frames(client, n + 2)
    assert client.get("/api/snapshot").json()["detections"]["green"]["bbox"][0] == 80  # its preset range again
    assert client.post("/api/calibration/undo").status_code == 409


def test_sessions_pause_start_reset(client):
    wait_frames(client, 1)
    r = client.post("/api/sessions", json={"action": "pause"})
    assert r.status_code == 200
    first = r.json()["current"]
    t0 = time.time()
    while client.get("/api/status").json()["worker"]["state"] != "paused" and time.time() - t0 < 10:
        time.sleep(0.05)
    assert client.get("/api/status").json()["worker"]["paused"] is True
    client.post("/api/sessions", json={"action": "start"})
    # a reset forgets placed parts: the teacher's control
    assert client.post("/api/sessions", json={"action": "reset"}).status_code == 403  # no password set yet
    client.post("/api/auth/setup", json={"password": PASSWORD})
    r = client.post("/api/sessions", json={"action": "reset"}).json()
    assert r["current"] != first
    assert [s["id"] for s in r["sessions"]][:2] == [r["current"], first]
    assert client.post("/api/sessions", json={"action": "explode"}).status_code == 422


def test_modes_reject_unknown_task(client):
    r = client.get("/api/modes").json()
    assert r["current"] == "none" and "learning" in r["modes"]
    bad = client.post("/api/modes", json={"mode": "guidance", "task": "no-such-task"})
    assert bad.status_code == 422 and "no-such-task" in bad.json()["detail"]
    bad = client.post("/api/modes", json={"mode": "dancing"})
    assert bad.status_code == 422


def test_mode_choices_offer_the_scene_that_fits(client):
    wait_frames(client, 1)
    r = client.get("/api/modes").json()
    assert r["source"] == "synthetic:"
    learning = [c for c in r["choices"] if c["mode"] == "learning"]
    # the synthetic table's two cubes carry no preset sentence: only the simulated learning scenes are offered
    assert learning and all(c["switches_source"] and c["source"].startswith("sim:learning-") for c in learning)
    assert {"mode": "none", "task": None, "title": "tracking only", "source": "synthetic:",
            "switches_source": False} in r["choices"]
    bad = client.post("/api/modes", json={"mode": "learning", "task": "learning-4-words"})
    assert bad.status_code == 422
    assert "needs the parts" in bad.json()["detail"] and "sim:learning-4" in bad.json()["detail"]
    # leaving a non-simulated source is the teacher's choice
    r = client.post("/api/modes", json={"mode": "learning", "task": "learning-4-words", "source": "sim:learning-4"})
    assert r.status_code == 403
    r = client.post("/api/modes", json={"mode": "guess", "source": "recording:/etc"})
    assert r.status_code == 422 and "simulated scene" in r.json()["detail"]
    assert client.get("/api/modes").json()["current"] == "none"  # nothing changed


def test_teacher_tasks_need_password(client):
    assert client.post("/api/tasks", json=TASK).status_code == 403  # no password set yet
    assert client.get("/api/auth").json() == {"configured": False, "logged_in": False}
    assert client.post("/api/auth/setup", json={"password": PASSWORD}).status_code == 200
    client.cookies.clear()
    assert client.post("/api/auth/setup", json={"password": "takeover"}).status_code == 403
    r = client.post("/api/tasks", json=TASK, headers={"X-Teacher-Password": "wrong"})
    assert r.status_code == 401
    assert client.post("/api/auth/login", json={"password": "wrong"}).status_code == 401
    r = client.post("/api/tasks", json=TASK, headers={"X-Teacher-Password": PASSWORD})
    assert r.status_code == 201, r.text
    rec = r.json()
    assert rec["ref"] == f"teacher:{rec['id']}" and rec["task"]["words"] == TASK["words"]
    # learners read without a password
    assert client.get("/api/tasks").json()["tasks"][0]["task"]["source_sentence"] == TASK["source_sentence"]
    assert client.get(f"/api/tasks/{rec['id']}").status_code == 200
    assert client.get("/api/tasks/999").status_code == 404
    assert client.delete(f"/api/tasks/{rec['id']}").status_code == 401
    # login → cookie → edit and delete
    assert client.post("/api/auth/login", json={"password": PASSWORD}).json()["logged_in"] is True
    html = {**TASK, "words": ["<script>alert(1)</script>", "gusta", "el", "café"]}
    r = client.put(f"/api/tasks/{rec['id']}", json=html)
    assert r.status_code == 200 and r.json()["task"]["words"][0] == "<script>alert(1)</script>"
    modes = client.get("/api/modes").json()
    assert any(t["id"] == rec["ref"] and t["mode"] == "learning" for t in modes["tasks"])
    assert client.delete(f"/api/tasks/{rec['id']}").status_code == 200
    assert client.get("/api/tasks").json()["tasks"] == []
    # a task that is gone: editing or deleting it again is a 404 naming the id
    r = client.put(f"/api/tasks/{rec['id']}", json=TASK)
    assert r.status_code == 404 and str(rec["id"]) in r.json()["detail"]
    assert client.delete(f"/api/tasks/{rec['id']}").status_code == 404


def test_task_validation_messages(client):
    client.post("/api/auth/setup", json={"password": PASSWORD})
    r = client.post("/api/tasks", json={**TASK, "words": ["Me", "  "]})
    assert r.status_code == 422
    errs = r.json()["detail"]
    assert any(e["loc"][:2] == ["body", "words"] and "word 2 is empty" in e["msg"] for e in errs)
    r = client.post("/api/tasks", json={**TASK, "source_sentence": ""})
    assert {"loc": ["body", "source_sentence"], "msg": "must not be empty", "type": "string_too_short"} in r.json()[
        "detail"
    ]
    r = client.post("/api/tasks", json={**TASK, "words": ["solo"]})
    assert r.json()["detail"][0]["msg"] == "give at least 2 words"
    r = client.post("/api/tasks", json={**TASK, "alternatives": [["Me", "gusta", "café"]]})
    assert r.status_code == 422 and "alternatives[0]" in str(r.json()["detail"])
    r = client.post("/api/tasks", json={**TASK, "colour": "red"})
    assert r.status_code == 422  # unknown fields are refused


def test_websocket_without_frames_ends_when_client_leaves(tmp_path):
    """A client that leaves while no frame comes (the source cannot open) must not keep its handler alive."""

    def broken(_spec):
        raise OSError("camera 7 not found")

    with app_client(tmp_path, broken, source="camera:7") as c:
        worker = c.app.state.assembly.worker
        with c.websocket_connect("/ws"):
            t0 = time.time()
            while not worker._listeners and time.time() - t0 < 5:
                time.sleep(0.02)
            assert len(worker._listeners) == 1
        t0 = time.time()
        while worker._listeners and time.time() - t0 < 5:
            time.sleep(0.02)
        assert worker._listeners == []
        st = c.get("/api/status").json()
        assert st["worker"]["state"] in ("error", "starting")
        assert any("camera 7 not found" in e["message"] for e in st["worker"]["errors"])


def test_drawn_box_survives_source_reopen(tmp_path):
    """A part placed by hand stays placed when the source ends and is reopened (loop) — until a reset."""

    def no_poses(_spec):
        src = SyntheticTable(n_frames=15)
        src.initial_poses = {}
        return src

    with app_client(tmp_path, no_poses, source="synthetic:", max_fps=100, teacher_password=PASSWORD) as c:
        wait_frames(c, 2)
        assert c.get("/api/snapshot").json()["poses"] == {}
        r = c.post("/api/boxes", json={"x": 38, "y": 58, "w": 14, "h": 14})
        assert r.status_code == 200 and r.json()["part"] == "red"
        opens = c.get("/api/status").json()["worker"]["source_opens"]
        t0 = time.time()
        while c.get("/api/status").json()["worker"]["source_opens"] <= opens and time.time() - t0 < 20:
            time.sleep(0.05)
        wait_frames(c, 1)
        assert set(c.get("/api/snapshot").json()["poses"]) == {"red"}
        assert c.post("/api/sessions", json={"action": "reset"}).status_code == 401
        c.post("/api/sessions", json={"action": "reset"}, headers={"X-Teacher-Password": PASSWORD})
        t0 = time.time()
        while time.time() - t0 < 20:
            snap = c.get("/api/snapshot").json()
            if snap["poses"] == {}:
                break
            time.sleep(0.05)
        assert c.get("/api/snapshot").json()["poses"] == {}


class TwoRedCubes(SyntheticTable):
    """The synthetic table with a second red square where the green one was: two identical parts."""

    def __init__(self):
        super().__init__(n_frames=100_000)
        h, w = self.color.shape[:2]
        self.color[h // 2 : h // 2 + 10, w // 2 : w // 2 + 10] = (210, 30, 35)


def test_identical_parts_keep_their_names(tmp_path):
    with app_client(tmp_path, lambda spec: TwoRedCubes(), source="synthetic:", max_fps=100) as c:
        wait_frames(c, 2)
        assert c.get("/api/identical-parts").json() == {"colour": None, "parts": []}
        r = c.post("/api/identical-parts", json={"colour": "red", "x": 100, "y": 20, "w": 20, "h": 20})
        assert r.status_code == 422 and "no part in the box" in r.json()["detail"]  # bare table
        assert c.post("/api/identical-parts", json={"colour": "red", "x": 38, "y": 58, "w": 14, "h": 14}).json()[
            "parts"] == ["red #1"]
        r = c.post("/api/identical-parts", json={"colour": "red", "x": 78, "y": 58, "w": 14, "h": 14})
        assert r.json() == {"colour": "red", "parts": ["red #1", "red #2"]}
        n = wait_frames(c, 0)["worker"]["frame_index"]
        wait_frames(c, n + 3)
        parts = c.get("/api/snapshot").json()["identical_parts"]
        assert set(parts) == {"red #1", "red #2"} and all(p["seen"] for p in parts.values())
        # each keeps its own square: #1 the left one (x 40..49), #2 the right one (x 80..89)
        assert 40 <= parts["red #1"]["center"][0] <= 50 and 80 <= parts["red #2"]["center"][0] <= 90
        assert c.delete("/api/identical-parts").json()["parts"] == []
