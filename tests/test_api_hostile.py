"""Hostile input at the HTTP edge: every case answers a clear 4xx (never a 500, never a 2xx it should not).

The app runs on the synthetic test table (tests/test_worker.py); limits are set small where a case needs them,
so nothing here waits for a bucket to refill.
"""

from __future__ import annotations

import logging

import pytest
from api_client import app_client, app_settings, wait_frames
from test_worker import SyntheticTable

from app.routes.parts import inside_image
from app.server import create_app
from tracker.assembly.presets import PRESET_DIR

PASSWORD = "profesora-1"
TEACHER = {"X-Teacher-Password": PASSWORD}
TASK = {"source_sentence": "Μου αρέσει ο καφές", "words": ["Me", "gusta", "el", "café"]}


def table(_spec):
    return SyntheticTable(n_frames=100_000)


@pytest.fixture()
def client(tmp_path):
    with app_client(
        tmp_path, table, source="synthetic:", max_fps=60, teacher_password=PASSWORD, learner_burst=1000
    ) as c:
        yield c


def detail(r) -> str:
    return str(r.json()["detail"])


def test_task_reference_is_an_allow_list(client):
    for bad in ("../../../../etc/passwd", "../tasks/guidance-5-cubes", "/etc/hostname", "guidance 5", "x" * 99):
        r = client.post("/api/modes", json={"mode": "guidance", "task": bad})
        assert r.status_code == 422, (bad, r.text)
        assert "unknown task" in detail(r)
        assert str(PRESET_DIR) not in detail(r)  # no path of the machine in the answer
    for bad in ("teacher:" + "9" * 400, "teacher:9223372036854775808", "teacher:-1", "teacher:0", "teacher:1x"):
        r = client.post("/api/modes", json={"mode": "learning", "task": bad})
        assert r.status_code == 422, (bad, r.text)
        assert len(detail(r)) < 300  # the huge number is not echoed back
    r = client.post("/api/modes", json={"mode": "learning", "task": "teacher:12345"})
    assert r.status_code == 422 and "no teacher task with id 12345" in detail(r)
    assert client.get("/api/modes").json()["current"] == "none"  # nothing changed


def test_task_ids_out_of_range_are_422(client):
    for path in ("/api/tasks/9223372036854775808", "/api/tasks/" + "9" * 400, "/api/tasks/0", "/api/tasks/-3"):
        assert client.get(path).status_code == 422, path
        assert client.delete(path, headers=TEACHER).status_code == 422, path
    assert client.get("/api/tasks/2147483647").status_code == 404


def test_non_finite_and_huge_box_numbers_are_refused(client):
    wait_frames(client, 2)
    for raw in (
        '{"x": Infinity, "y": 10, "w": 5, "h": 5}',
        '{"x": 10, "y": NaN, "w": 5, "h": 5}',
        '{"x": 10, "y": 10, "w": 1e400, "h": 5}',
        '{"x": 10, "y": 10, "w": 1000000000, "h": 1000000000}',
        '{"x": 10, "y": 10, "w": 5, "h": ' + "9" * 5000 + "}",
    ):
        json_h = {"content-type": "application/json"}
        r = client.post("/api/boxes", content=raw, headers=json_h)
        assert r.status_code in (400, 422), (raw[:60], r.status_code, r.text[:200])
        r = client.post("/api/identical-parts", content=raw.replace("{", '{"colour": "red", ', 1), headers=json_h)
        assert r.status_code in (400, 422), (raw[:60], r.status_code, r.text[:200])
    r = client.post("/api/identical-parts", json={"colour": "red", "x": 500, "y": 400, "w": 20, "h": 20})
    assert r.status_code == 422 and "outside the 160×120 image" in detail(r)
    # inside the bounds of the model, but outside this 160x120 image
    r = client.post("/api/boxes", json={"x": 500, "y": 400, "w": 20, "h": 20})
    assert r.status_code == 422 and "outside the 160×120 image" in detail(r)
    assert client.get("/api/boxes").json()["boxes"] == []  # nothing was placed


def test_box_overhanging_the_image_is_cut_to_it():
    assert inside_image((38, 58, 14, 14), 160, 120) == (38, 58, 14, 14)
    assert inside_image((150, 100, 14, 24), 160, 120) == (150, 100, 10, 20)  # a drag that ended past the edge
    for off in ((150, 100, 30, 30), (200, 10, 5, 5), (0, 119.5, 4, 4)):
        with pytest.raises(ValueError, match="outside the 160×120 image"):
            inside_image(off, 160, 120)


def test_strings_and_lists_are_bounded(client, caplog):
    caplog.set_level(logging.DEBUG)
    huge = "a" * 20_000_000
    r = client.post("/api/modes", json={"mode": "guidance", "task": huge})
    assert r.status_code == 413 and "too large" in detail(r)
    r = client.post("/api/modes", json={"mode": "guidance", "task": "b" * 5000})
    assert r.status_code == 422
    r = client.post("/api/parts/auto-place", json={"names": ["red"] * 1000})
    assert r.status_code == 422
    r = client.post("/api/boxes", json={"x": 1, "y": 1, "w": 5, "h": 5, "part": "../x"})
    assert r.status_code == 422
    r = client.post("/api/auth/login", json={"password": "p" * 5000})
    assert r.status_code == 422
    assert all(len(rec.getMessage()) < 2000 for rec in caplog.records)  # no huge input in the log


def test_body_limit_without_content_length(client):
    def chunks():
        for _ in range(100):
            yield b"x" * 10_000

    r = client.post("/api/modes", content=chunks(), headers={"content-type": "application/json"})
    assert r.status_code == 413
    assert client.get("/api/status").status_code == 200  # the server keeps running


def test_sentence_text_is_checked(client):
    bad = [
        {**TASK, "source_sentence": "   "},
        {**TASK, "source_sentence": "caf\x00é"},
        {**TASK, "words": ["Me", "\x00"]},
        {**TASK, "words": ["Me", "gus\x07ta"]},
        {**TASK, "words": ["w"] * 41},
        {**TASK, "words": ["Me", "x" * 81]},
        {**TASK, "source_sentence": "s" * 501},
        {**TASK, "distractors": ["d"] * 41},
    ]
    for body in bad:
        r = client.post("/api/tasks", json=body, headers=TEACHER)
        assert r.status_code == 422, (str(body)[:80], r.text[:200])
    assert client.get("/api/tasks").json()["tasks"] == []


def test_state_changing_controls_need_the_teacher(client):
    wait_frames(client, 1)
    before = client.get("/api/status").json()
    assert client.post("/api/sources", json={"source": "sim:static"}).status_code == 401
    assert client.post("/api/sessions", json={"action": "reset"}).status_code == 401
    assert client.post("/api/tasks", json=TASK).status_code == 401
    after = client.get("/api/status").json()
    assert after["source"] == before["source"] and after["session_id"] == before["session_id"]
    # learner actions stay open
    assert client.post("/api/sessions", json={"action": "start"}).status_code == 200
    assert client.post("/api/modes", json={"mode": "none"}).status_code == 200


def test_sources_only_from_the_data_folders(client, tmp_path):
    inside = tmp_path / "data" / "rec1"
    inside.mkdir(parents=True)
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "data" / "link").symlink_to(tmp_path / "elsewhere")
    client.app.state.assembly.settings.recording_dirs = [str(tmp_path / "data")]
    for spec in (
        "recording:/etc",
        f"recording:{tmp_path / 'data' / '..' / 'elsewhere'}",
        f"recording:{tmp_path / 'data' / 'link'}",
        f"recording:{tmp_path / 'data' / 'missing'}",
        "sim:no-such-scenario",
        "camera:../../dev/x",
        "sim:static\x00",
        "file:/etc/passwd",
        "/etc",
    ):
        r = client.post("/api/sources", json={"source": spec}, headers=TEACHER)
        assert r.status_code == 422, (spec, r.text)
    assert client.get("/api/sources").json()["current"] == "synthetic:"
    r = client.post("/api/sources", json={"source": f"recording:{inside}"}, headers=TEACHER)
    assert r.status_code == 200 and r.json()["current"] == f"recording:{inside}"


def test_wrong_passwords_are_throttled(tmp_path):
    with app_client(tmp_path, table, teacher_password=PASSWORD, login_burst=3, login_refill_s=3600) as c:
        for _ in range(3):
            assert c.post("/api/auth/login", json={"password": "wrong-password"}).status_code == 401
        r = c.post("/api/auth/login", json={"password": "wrong-password"})
        assert r.status_code == 429 and int(r.headers["retry-after"]) >= 1
        # the throttle holds for the header password too, and for the right password from this client
        assert c.post("/api/tasks", json=TASK, headers={"X-Teacher-Password": "nope-nope-nope"}).status_code == 429
        assert c.post("/api/auth/login", json={"password": PASSWORD}).status_code == 429
        # another client is not blocked; right passwords do not use up its allowance
        other = type(c)(c.app, client=("127.0.0.2", 4000))  # the same running app, another address
        for _ in range(5):
            assert other.post("/api/auth/login", json={"password": PASSWORD}).status_code == 200


def test_password_rule_and_remote_first_setup(tmp_path):
    with app_client(tmp_path, table) as c:
        remote = type(c)(c.app, client=("192.168.1.20", 4000))
        r = remote.post("/api/auth/setup", json={"password": "a-long-enough-password"})
        assert r.status_code == 403 and "server machine" in detail(r)
        assert c.get("/api/auth").json()["configured"] is False
        for weak in ("short", "123456789", "aaaaaaaaaaaa"):
            r = c.post("/api/auth/setup", json={"password": weak})
            assert r.status_code == 422, weak
        assert c.post("/api/auth/setup", json={"password": "a-long-enough-password"}).status_code == 200


def test_weak_environment_password_refuses_to_start(tmp_path):
    with pytest.raises(ValueError, match="at least 10 characters"):
        create_app(app_settings(tmp_path, teacher_password="1234"), open_source=table)


def test_learner_actions_are_rate_limited(tmp_path):
    with app_client(tmp_path, table, learner_burst=3, learner_rate=0.001) as c:
        for _ in range(3):
            assert c.post("/api/modes", json={"mode": "none"}).status_code == 200
        r = c.post("/api/boxes", json={"x": 1, "y": 1, "w": 5, "h": 5})
        assert r.status_code == 429 and int(r.headers["retry-after"]) >= 1
        assert c.get("/api/modes").status_code == 200  # reading stays open


def test_api_requests_are_rate_limited(tmp_path):
    with app_client(tmp_path, table, api_burst=5, api_rate=0.001) as c:
        codes = [c.get("/api/status").status_code for _ in range(7)]
        assert codes[:5] == [200] * 5 and codes[5:] == [429, 429]
        assert c.get("/").status_code == 200  # the page itself is not an API request


def test_host_and_origin_checks(client):
    r = client.get("/api/status", headers={"host": "evil.example"})
    assert r.status_code == 400 and "host not allowed" in detail(r)
    r = client.post("/api/modes", json={"mode": "none"}, headers={"origin": "http://evil.example"})
    assert r.status_code == 403 and "origin" in detail(r)
    r = client.post("/api/modes", json={"mode": "none"}, headers={"origin": "http://testserver"})
    assert r.status_code == 200
    from starlette.websockets import WebSocketDisconnect

    with pytest.raises(WebSocketDisconnect) as refused:
        with client.websocket_connect("/ws", headers={"origin": "http://evil.example"}) as ws:
            ws.receive_text()
    assert refused.value.code == 1008
    with client.websocket_connect("/ws", headers={"origin": "http://localhost:8000"}) as ws:
        assert "frame_index" in ws.receive_json()


def test_security_headers(client):
    for path in ("/", "/teacher", "/api/status", "/static/app.js"):
        h = client.get(path).headers
        assert "frame-ancestors 'none'" in h["content-security-policy"], path
        assert "script-src 'self'" in h["content-security-policy"]
        assert h["x-content-type-options"] == "nosniff"
        assert h["referrer-policy"] == "no-referrer"


def test_scene_may_be_framed_from_the_other_loopback_name_only():
    """A page on 127.0.0.1 or localhost may frame the viser port of either loopback name (the panel uses the other
    one, so the browser draws the scene in its own process); a page on another host only its own host's."""
    from app.middleware import panel_csp

    csp = panel_csp(8080)

    def frame_src(host: str) -> set[str]:
        policy = csp({"path": "/", "headers": [(b"host", host.encode())]})
        return set(next(p for p in policy.split("; ") if p.startswith("frame-src")).split()[1:])

    assert {"http://localhost:8080", "http://127.0.0.1:8080"} <= frame_src("127.0.0.1:8000")
    assert {"http://localhost:8080", "http://127.0.0.1:8080"} <= frame_src("localhost:8000")
    assert frame_src("lab-pc.example:8000") == {"http://lab-pc.example:8080", "https://lab-pc.example:8080"}
