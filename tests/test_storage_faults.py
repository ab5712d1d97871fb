"""Database faults: a damaged, deleted, locked or unusable SQLite file gets a clear answer and loses nothing.

Faults are real: bytes of the file overwritten, the file deleted under the running server, a write lock held
by another connection (as a backup tool or the sqlite3 shell would). Every case answers 503 with a JSON
message naming the file (never a 500) and leaves stored data and the server's state as they were.
"""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest
from api_client import app_client, wait_frames
from test_worker import SyntheticTable

from app.cli import main
from app.server import create_app
from app.settings import Settings
from app.storage import Storage, StorageError

PASSWORD = "profesora-1"
TEACHER = {"X-Teacher-Password": PASSWORD}
TASK = {"source_sentence": "Μου αρέσει ο καφές", "words": ["Me", "gusta", "el", "café"]}


def table(_spec):
    return SyntheticTable(n_frames=100_000)


def filled_database(path: Path, n_tasks: int = 120) -> Path:
    """A database holding ``n_tasks`` tasks (several pages), checkpointed into the main file."""
    Storage(path)
    rows = [(json.dumps({**TASK, "source_sentence": f"{i} " + "x" * 300}), 0.0, 0.0) for i in range(n_tasks)]
    con = sqlite3.connect(path)
    with con:  # one transaction (quicker than n_tasks commits)
        con.executemany("INSERT INTO tasks (data, created_at, updated_at) VALUES (?, ?, ?)", rows)
    con.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    con.close()
    return path


def damage(path: Path, page: int = 4) -> None:
    """Overwrite the start of page ``page`` (0-based, 4096-byte pages) with garbage."""
    data = bytearray(path.read_bytes())
    data[4096 * page : 4096 * page + 100] = b"\xff" * 100
    path.write_bytes(bytes(data))


def test_database_uses_wal(tmp_path):
    Storage(tmp_path / "a.db")
    con = sqlite3.connect(tmp_path / "a.db")
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    con.close()


def test_damaged_file_refuses_to_start_naming_it(tmp_path, capsys):
    db = filled_database(tmp_path / "agent.sqlite3")
    damage(db)
    before = db.read_bytes()
    with pytest.raises(StorageError, match=r"agent\.sqlite3.*damaged.*db restore"):
        create_app(Settings(database=str(db), viser_port=0, mode="none"), open_source=table)
    # the command line says the same and exits with 1 before serving anything
    assert main(["serve", "--database", str(db), "--viser-port", "0", "--port", "0"]) == 1
    assert "agent.sqlite3" in capsys.readouterr().err
    assert db.read_bytes() == before  # nothing was written to the damaged file
    not_sqlite = tmp_path / "notes.sqlite3"
    not_sqlite.write_bytes(b"these are not the tables you are looking for" * 100)
    with pytest.raises(StorageError, match="notes.sqlite3"):
        Storage(not_sqlite)


def test_damaged_file_served_read_only(tmp_path):
    db = filled_database(tmp_path / "agent.sqlite3", n_tasks=3)
    damage(db, page=1)
    with app_client(tmp_path, table, database=str(db), on_damaged_database="read-only", teacher_password=PASSWORD) as c:
        st = c.get("/api/status").json()
        assert st["storage"]["read_only"] is True and "agent.sqlite3" in st["storage"]["problem"]
        assert st["session_id"] is None  # no session is recorded in a read-only database
        r = c.post("/api/tasks", json=TASK, headers=TEACHER)
        assert r.status_code == 503 and "read-only" in r.json()["detail"]
        for path in ("/api/tasks", "/api/sessions", "/api/tasks/1"):
            assert c.get(path).status_code in (200, 404, 503), path  # never a 500
        assert c.get("/api/modes").status_code == 200  # presets still listed
        # the source can still be switched: it writes nothing but a session, which is not recorded here
        assert c.post("/api/sources", json={"source": "sim:static"}, headers=TEACHER).status_code == 200


def test_locked_database_changes_nothing(tmp_path):
    with app_client(tmp_path, table, source="synthetic:", teacher_password=PASSWORD) as c:
        st = wait_frames(c, 1)
        state = c.app.state.assembly
        state.storage.timeout = 0.2
        other = sqlite3.connect(state.storage.path, isolation_level=None)
        other.execute("BEGIN IMMEDIATE")  # another program holds the write lock
        try:
            r = c.post("/api/sources", json={"source": "sim:static"}, headers=TEACHER)
            assert r.status_code == 503 and "locked" in r.json()["detail"] and "agent.sqlite3" in r.json()["detail"]
            r = c.post("/api/sessions", json={"action": "reset"}, headers=TEACHER)
            assert r.status_code == 503
            assert c.post("/api/tasks", json=TASK, headers=TEACHER).status_code == 503
            now = c.get("/api/status").json()
            assert now["source"] == "synthetic:" and now["session_id"] == st["session_id"]  # nothing half-applied
            assert "locked" in now["storage"]["problem"]
            assert c.get("/api/tasks").json()["tasks"] == []  # reads go on (WAL)
        finally:
            other.execute("ROLLBACK")
            other.close()
        r = c.post("/api/sources", json={"source": "sim:static"}, headers=TEACHER)
        assert r.status_code == 200 and r.json()["current"] == "sim:static"
        assert c.get("/api/status").json()["storage"]["problem"] is None


def test_deleted_file_is_reported_not_recreated(tmp_path):
    with app_client(tmp_path, table, source="synthetic:", teacher_password=PASSWORD) as c:
        wait_frames(c, 1)
        db = c.app.state.assembly.storage.path
        assert c.post("/api/tasks", json=TASK, headers=TEACHER).status_code == 201
        for f in db.parent.glob(db.name + "*"):
            f.unlink()
        assert "missing" in c.get("/api/status").json()["storage"]["problem"]
        for r in (c.get("/api/tasks"), c.post("/api/tasks", json=TASK, headers=TEACHER)):
            assert r.status_code == 503 and "missing" in r.json()["detail"], r.text
        assert not db.exists()  # not silently replaced by an empty database
        assert c.get("/api/modes").status_code == 200


def test_damage_while_running_is_503(tmp_path):
    db = filled_database(tmp_path / "agent.sqlite3", n_tasks=60)
    with app_client(tmp_path, table, database=str(db)) as c:
        damage(db, page=2)
        damage(db, page=3)
        codes = {c.get("/api/tasks").status_code, c.get("/api/tasks/5").status_code}
        assert codes <= {200, 503} and 503 in codes, codes
        assert c.get("/api/status").status_code == 200


def test_backup_and_restore_commands(tmp_path, capsys):
    db = filled_database(tmp_path / "agent.sqlite3", n_tasks=40)
    backup = tmp_path / "backups" / "monday.sqlite3"
    assert main(["db", "--database", str(db), "backup", str(backup)]) == 0
    assert "40 teacher task(s)" in capsys.readouterr().out
    assert main(["db", "--database", str(db), "backup", str(backup)]) == 1  # no silent overwrite
    assert "exists" in capsys.readouterr().err
    damage(db)
    assert main(["db", "--database", str(db), "check"]) == 1
    assert "damaged" in capsys.readouterr().err
    assert main(["db", "--database", str(db), "restore", str(backup)]) == 0
    out = capsys.readouterr().out
    assert "restored" in out and "kept as" in out
    assert len(Storage(db).list_tasks()) == 40
    kept = [p for p in tmp_path.glob("agent.sqlite3.before-restore-*") if not p.name.endswith(("-wal", "-shm"))]
    assert len(kept) == 1 and kept[0].stat().st_size > 0  # the damaged file is kept, not deleted
    # a damaged backup is refused and the database stays as it is
    bad = tmp_path / "bad.sqlite3"
    bad.write_bytes(backup.read_bytes())
    damage(bad)
    before = db.read_bytes()
    assert main(["db", "--database", str(db), "restore", str(bad)]) == 1
    assert "damaged" in capsys.readouterr().err and db.read_bytes() == before
