"""Learner results: the recorder follows mode states (as ``ModeState.to_dict()`` gives them), stores steps,
wrong placements and hints in batches, keeps them through a database outage, and the teacher reads them as JSON
and CSV. Runs on SQLite and on a real PostgreSQL server."""

from __future__ import annotations

import csv
import io
import sqlite3

from api_client import app_client
from test_worker import SyntheticTable

from app.results import ResultsRecorder
from app.storage import Storage

PASSWORD = "profesora-1"
TEACHER = {"X-Teacher-Password": PASSWORD}


def guidance_state(done: int, total: int = 3, events=(), warning=None, complete=False) -> dict:
    nxt = None if complete else {"index": done, "part": f"p{done + 1}", "anchor": "base", "direction": "on top of"}
    return {"mode": "guidance", "task_id": "g", "progress": {"done": done, "total": total, "unit": "steps"},
            "complete": complete, "events": list(events), "warning": warning, "next_step": nxt, "step": done}


WRONG = {"t": 1.0, "type": "connected", "parts": ["p1", "p3"], "expected": False}
RIGHT = {"t": 1.0, "type": "connected", "parts": ["p1", "base"], "expected": True}


def play_guidance(rec: ResultsRecorder, round_: int = 1, t0: float = 1000.0) -> None:
    """A learner: step 1 in 4 s with one wrong placement, step 2 in 6 s with a warning shown twice (one hint),
    step 3 in 2 s; the structure is complete at t0 + 12."""
    frames = [
        (0.0, guidance_state(0)),
        (1.0, guidance_state(0, events=[WRONG])),
        (4.0, guidance_state(1, events=[RIGHT])),
        (5.0, guidance_state(1, warning="The p1 part came apart")),
        (5.5, guidance_state(1, warning="The p1 part came apart")),
        (6.0, guidance_state(1)),
        (10.0, guidance_state(2)),
        (12.0, guidance_state(3, complete=True)),
        (13.0, guidance_state(3, complete=True)),
    ]
    for t, state in frames:
        rec.observe("guidance", state, round_, t0 + t)


def test_recorder_steps_errors_hints(database):
    s = Storage(database)
    sid = s.start_session("sim:guidance-demo", "guidance", "guidance-5-cubes", station="bench-1")
    rec = ResultsRecorder(s)
    rec.switch(sid, "guidance")
    rec.observe("guess", guidance_state(2), 1, 999.0)  # a frame of the old pipeline: ignored
    play_guidance(rec)
    assert rec.pending() == 3 and rec.flush() and rec.pending() == 0
    got = s.results()["sessions"][0]
    assert (got["steps_total"], got["wrong_placements"], got["hints"], got["completed_at"]) == (3, 1, 1, 1012.0)
    steps = [(x["step"], x["verdict"], x["duration_s"], x["wrong_placements"], x["hints"]) for x in got["steps"]]
    assert steps == [(1, "done", 4.0, 1, 0), (2, "done", 6.0, 0, 1), (3, "done", 2.0, 0, 0)]
    assert got["steps"][0]["label"] == "p1 on top of base"
    # the source loops: attempt 2 stops after step 1; ending the session stores step 2 as unfinished
    rec.observe("guidance", guidance_state(0), 2, 2000.0)
    rec.observe("guidance", guidance_state(1), 2, 2003.0)
    rec.switch(None, None, now=2010.0)
    rec.flush()
    second = [x for x in s.results()["sessions"][0]["steps"] if x["attempt"] == 2]
    assert [(x["step"], x["verdict"], x["duration_s"]) for x in second] == [(1, "done", 3.0), (2, "unfinished", 7.0)]


def test_learning_wrong_words_and_misread_row():
    """Learning: a word put in a wrong position is a wrong placement; a full row in a wrong order is a hint."""
    rec = ResultsRecorder(storage=None)  # no storage needed: the buffer is inspected

    def state(placed: list, complete=False):
        expected = ["Me", "gusta", "el", "café"]
        verdicts = [{"position": i + 1, "expected": w, "placed": placed[i] if i < len(placed) else None,
                     "correct": i < len(placed) and placed[i] == w} for i, w in enumerate(expected)]
        n = sum(v["correct"] for v in verdicts)
        return {"progress": {"done": n, "total": 4, "unit": "words"}, "complete": complete, "events": [],
                "verdicts": verdicts, "row": [f"c{i}" for i in range(len(placed))]}

    rec.switch(7, "learning", now=0.0)
    rec.observe("learning", state([]), 1, 0.0)
    rec.observe("learning", state(["Me", "el"]), 1, 2.0)  # word 1 right (step 1 done), "el" wrong at position 2
    rec.observe("learning", state(["Me", "el", "gusta", "café"]), 1, 5.0)  # full row, wrong order: a hint
    rec.observe("learning", state(["Me", "gusta", "el", "café"], complete=True), 1, 9.0)
    steps = rec._steps
    assert [(x["step"], x["duration_s"]) for x in steps] == [(1, 2.0), (2, 3.0), (3, 4.0), (4, 0.0)]
    assert sum(x["wrong_placements"] for x in steps) == 2  # "el" at 2, then "gusta" at 3
    assert sum(x["hints"] for x in steps) == 1
    assert steps[0]["label"] == "word 1: Me"


def test_results_kept_through_an_outage(tmp_path):
    db = tmp_path / "agent.sqlite3"
    s = Storage(db)
    sid = s.start_session("sim:guidance-demo", "guidance", None, station="bench-1")
    rec = ResultsRecorder(s)
    rec.switch(sid, "guidance")
    play_guidance(rec)
    s.timeout = 0.1
    other = sqlite3.connect(db, isolation_level=None)
    other.execute("BEGIN IMMEDIATE")  # the database cannot be written for a while
    try:
        assert rec.flush() is False and rec.pending() == 3
        assert s.results()["sessions"][0]["steps"] == []
    finally:
        other.execute("ROLLBACK")
        other.close()
    assert rec.flush() is True and rec.pending() == 0
    got = s.results()["sessions"][0]
    assert [x["step"] for x in got["steps"]] == [1, 2, 3] and got["wrong_placements"] == 1


def table(_spec):
    return SyntheticTable(n_frames=100_000)


def test_results_api_and_csv_are_teacher_only(tmp_path):
    with app_client(tmp_path, table, source="synthetic:", teacher_password=PASSWORD, autostart=False,
                    station="bench-9") as c:
        state = c.app.state.assembly
        store = state.storage
        for station, label in (("bench-1", "=cmd()"), ("bench-2", "p1")):
            sid = store.start_session("sim:guidance-demo", "guidance", None, station=station)
            rec = ResultsRecorder(store)
            rec.switch(sid, "guidance")
            play_guidance(rec)
            rec._steps[0]["label"] = label
            rec.flush()
        assert c.get("/api/results").status_code == 401
        assert c.get("/api/results.csv").status_code == 401
        r = c.get("/api/results", headers=TEACHER).json()
        assert r["stations"] == ["bench-1", "bench-2"] and r["tasks"] == ["guidance-5-cubes"]
        assert [x["step"] for x in r["steps"]] == [1, 2, 3]
        assert r["steps"][0] == {"step": 1, "n": 2, "mean_time_s": 4.0, "error_rate": 1.0, "hints": 0}
        assert r["steps"][1]["error_rate"] == 0.0 and r["steps"][1]["hints"] == 2
        assert [g["completed"] for g in r["by_station"]] == [1, 1]
        one = c.get("/api/results", params={"station": "bench-2"}, headers=TEACHER).json()
        assert [x["station"] for x in one["sessions"]] == ["bench-2"] and one["steps"][0]["n"] == 1
        assert c.get("/api/results", params={"station": "x\x01"}, headers=TEACHER).status_code == 422
        resp = c.get("/api/results.csv", params={"station": "bench-1"}, headers=TEACHER)
        assert resp.status_code == 200 and resp.headers["content-type"].startswith("text/csv")
        assert "attachment" in resp.headers["content-disposition"]
        rows = list(csv.DictReader(io.StringIO(resp.text)))
        assert [r["step"] for r in rows] == ["1", "2", "3"] and {r["station"] for r in rows} == {"bench-1"}
        assert rows[0]["label"] == "'=cmd()"  # not run as a formula by a spreadsheet
        assert rows[1]["duration_s"] == "6.0" and rows[0]["wrong_placements"] == "1"


def test_recorder_never_raises_on_odd_states(tmp_path):
    class Snap:
        mode = "guidance"
        mode_state = {"progress": "garbage"}
        source = {"round": 1}
        wall_time = 5.0

    s = Storage(tmp_path / "a.db")
    rec = ResultsRecorder(s)
    rec.switch(s.start_session("x", "guidance", None), "guidance")
    rec.on_frame(Snap())  # logged, not raised: the worker goes on
    assert rec.pending() == 0
    Snap.mode_state = guidance_state(0)
    rec.on_frame(Snap())
    Snap.mode_state, Snap.wall_time = guidance_state(1), 8.0
    rec.on_frame(Snap())  # and the recorder still works afterwards
    assert rec.pending() == 1 and rec._steps[0]["duration_s"] == 3.0
