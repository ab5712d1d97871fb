"""SQLite storage and teacher auth on a real database file."""

from __future__ import annotations

import sqlite3

import pytest

from app.auth import TeacherAuth, hash_password, verify_password
from app.settings import Settings
from app.storage import SCHEMA_VERSION, Storage, StorageError

TASK = {"source_sentence": "Μου αρέσει ο καφές", "words": ["Me", "gusta", "el", "café"], "distractors": ["leche"]}


def test_tasks_survive_reopen(tmp_path):
    db = tmp_path / "sub" / "agent.sqlite3"
    s = Storage(db)
    rec = s.create_task(TASK)
    assert rec["id"] == 1
    s2 = Storage(db)  # a restart: a new Storage on the same file
    got = s2.get_task(rec["id"])
    assert got["data"] == TASK
    assert s2.update_task(rec["id"], {**TASK, "words": ["Me", "gusta", "la", "leche"]})["data"]["words"][2] == "la"
    assert [t["id"] for t in Storage(db).list_tasks()] == [1]
    assert s2.delete_task(1) is True
    assert s2.delete_task(1) is False
    assert Storage(db).list_tasks() == []
    assert s2.update_task(99, TASK) is None


def test_schema_version_recorded_and_newer_file_refused(tmp_path):
    db = tmp_path / "agent.sqlite3"
    assert Storage(db).schema_version() == SCHEMA_VERSION
    con = sqlite3.connect(db)
    with con:
        con.execute("INSERT INTO schema_version (version) VALUES (?)", (SCHEMA_VERSION + 1,))
    con.close()
    with pytest.raises(StorageError, match="newer than this program"):
        Storage(db)


def test_not_a_database_gives_clear_error(tmp_path):
    bad = tmp_path / "junk.sqlite3"
    bad.write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(StorageError, match="junk.sqlite3"):
        Storage(bad)


def test_database_url_forms():
    assert str(Settings(database="sqlite:///tmp/x.db").database_path()) == "tmp/x.db"
    assert str(Settings(database="sqlite:////abs/x.db").database_path()) == "/abs/x.db"
    with pytest.raises(ValueError, match="only SQLite"):
        Settings(database="postgresql://u@h/db").database_path()


def test_sessions_listed_newest_first(tmp_path):
    s = Storage(tmp_path / "a.db")
    a = s.start_session("sim:static", "guidance", None)
    b = s.start_session("sim:guess-1", "guess", "guess-structures")
    s.end_session(a, 42)
    rows = s.list_sessions()
    assert [r["id"] for r in rows] == [b, a]
    assert rows[1]["frames"] == 42 and rows[1]["ended_at"] is not None


def test_password_hash_is_salted_and_not_plaintext(tmp_path):
    h1, h2 = hash_password("secret-pw"), hash_password("secret-pw")
    assert h1 != h2 and "secret-pw" not in h1
    assert verify_password("secret-pw", h1) and not verify_password("wrong", h1)
    assert not verify_password("secret-pw", "garbage")
    s = Storage(tmp_path / "a.db")
    auth = TeacherAuth(s)
    assert not auth.is_configured
    with pytest.raises(ValueError, match="at least"):
        auth.setup("ab")
    auth.setup("lehrer-1234")
    with pytest.raises(PermissionError):
        auth.setup("another-password")
    stored = s.get_secret("teacher_password")
    assert "lehrer-1234" not in stored and stored.startswith("scrypt$")
    raw = (tmp_path / "a.db").read_bytes()
    assert b"lehrer-1234" not in raw
    assert auth.login("nope") is None
    token = auth.login("lehrer-1234")
    assert auth.check_token(token) and not auth.check_token("forged")
    auth.logout(token)
    assert not auth.check_token(token)


def test_env_password_replaces_stored_one(tmp_path):
    s = Storage(tmp_path / "a.db")
    TeacherAuth(s).setup("first-password")
    auth = TeacherAuth(s, env_password="from-the-env")
    assert auth.check_password("from-the-env") and not auth.check_password("first-password")
