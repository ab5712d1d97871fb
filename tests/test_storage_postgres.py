"""Two app instances (two stations) on one real PostgreSQL server: they share teacher tasks, sessions and results,
and both survive a restart of PostgreSQL (503 with a clear message while it is down, working again by themselves;
learner results made meanwhile are kept in memory and written once it is back) and of either station.
"""

from __future__ import annotations

import threading
from contextlib import ExitStack

import pytest
import sqlalchemy as sa
from api_client import app_client
from test_results import play_guidance
from test_worker import SyntheticTable

from app.results import ResultsRecorder
from app.storage import StorageUnavailable, head_revision, open_storage, sessions_table

PASSWORD = "profesora-1"
TEACHER = {"X-Teacher-Password": PASSWORD}
TASK = {"source_sentence": "Μου αρέσει ο καφές", "words": ["Me", "gusta", "el", "café"]}


def table(_spec):
    return SyntheticTable(n_frames=100_000)


def test_two_stations_share_one_postgres_and_survive_restarts(postgres_server, tmp_path):
    url = postgres_server.new_database()

    def station(name: str):
        return app_client(tmp_path / name, table, database=url, station=name, teacher_password=PASSWORD,
                          source="synthetic:", autostart=False)

    with ExitStack() as stack:
        first = ExitStack()
        a = first.enter_context(station("bench-1"))
        b = stack.enter_context(station("bench-2"))
        # a task written on one station is there on the other
        created = a.post("/api/tasks", json=TASK, headers=TEACHER)
        assert created.status_code == 201, created.text
        task_id = created.json()["id"]
        assert [t["id"] for t in b.get("/api/tasks").json()["tasks"]] == [task_id]
        # sessions of both stations land in one table; results are grouped by station
        assert a.post("/api/sessions", json={"action": "start"}).status_code == 200
        assert b.post("/api/sessions", json={"action": "start"}).status_code == 200
        ids = {c.app.state.assembly.session_id for c in (a, b)}
        assert len(ids) == 2 and None not in ids
        assert ids <= {s["id"] for s in b.get("/api/sessions").json()["sessions"]}
        store = a.app.state.assembly.storage
        with store.engine.connect() as con:
            rows = con.execute(sa.select(sessions_table.c.station).where(sessions_table.c.id.in_(ids))).all()
        stations = {r[0] for r in rows}
        assert stations == {"bench-1", "bench-2"}
        # learner results written by each station are read by the teacher on either
        recorders = []
        for c in (a, b):
            state = c.app.state.assembly
            rec = ResultsRecorder(state.storage)
            rec.switch(state.storage.start_session("sim:guidance-demo", "guidance", None,
                                                   station=state.settings.station), "guidance")
            recorders.append(rec)
        play_guidance(recorders[0])
        assert recorders[0].flush()
        seen = b.get("/api/results", headers=TEACHER).json()
        assert [x["station"] for x in seen["sessions"] if x["steps_done"]] == ["bench-1"]
        assert seen["steps"][0]["n"] == 1 and seen["stations"] == ["bench-1", "bench-2"]

        postgres_server.stop()
        try:
            for c in (a, b):
                r = c.get("/api/tasks")
                assert r.status_code == 503 and "unavailable" in r.json()["detail"], r.text
                assert "127.0.0.1" in r.json()["detail"] and PASSWORD not in r.json()["detail"]
                r = c.post("/api/tasks", json={**TASK, "source_sentence": "lost?"}, headers=TEACHER)
                assert r.status_code == 503 and "nothing was changed" in r.json()["detail"]
                st = c.get("/api/status")
                assert st.status_code == 200 and "unavailable" in st.json()["storage"]["problem"]
            play_guidance(recorders[1])  # a learner at bench-2 goes on working meanwhile
            assert recorders[1].flush() is False and recorders[1].pending() == 3  # kept in memory
        finally:
            postgres_server.start()

        # both recover without a restart of their own: the first request after the outage works
        for c in (a, b):
            r = c.get("/api/tasks")
            assert r.status_code == 200 and [t["id"] for t in r.json()["tasks"]] == [task_id]
            assert c.get("/api/status").json()["storage"]["problem"] is None
        second = b.post("/api/tasks", json={**TASK, "source_sentence": "después"}, headers=TEACHER)
        assert second.status_code == 201
        assert len(a.get("/api/tasks").json()["tasks"]) == 2
        assert recorders[1].flush() is True  # nothing of the outage is lost
        by_station = {g["station"]: g for g in a.get("/api/results", headers=TEACHER).json()["by_station"]}
        assert by_station["bench-2"]["completed"] == 1 and by_station["bench-2"]["wrong_placements"] == 1

        # a restart of one station: its session is ended, the other goes on, and it comes back with everything
        a_session = a.app.state.assembly.session_id
        first.close()
        ended = {x["id"]: x for x in b.get("/api/sessions").json()["sessions"]}[a_session]
        assert ended["ended_at"] is not None
        assert b.post("/api/tasks", json={**TASK, "source_sentence": "mientras"}, headers=TEACHER).status_code == 201
        a = stack.enter_context(station("bench-1"))
        assert len(a.get("/api/tasks").json()["tasks"]) == 3
        again = a.get("/api/results", params={"station": "bench-1"}, headers=TEACHER).json()
        assert again["by_station"][0]["completed"] == 1


def test_server_waits_for_its_database_at_start(postgres_server):
    """A station started before PostgreSQL (``--database-wait``) opens the database once it is up."""
    url = postgres_server.new_database()
    postgres_server.stop()
    timer = threading.Timer(1.0, postgres_server.start)
    try:
        with pytest.raises(StorageUnavailable, match="is unavailable"):
            open_storage(url, wait_s=0)  # without waiting: the clear message at once
        timer.start()
        store = open_storage(url, wait_s=120, poll_s=0.2)
    finally:
        if timer.is_alive() or timer.finished.is_set():
            timer.join()
        else:
            postgres_server.start()
    assert store.schema_version() == head_revision()
    assert store.create_task(TASK)["id"] == 1
