"""Storage and teacher auth on a real database: every test runs on a SQLite file and on a real PostgreSQL server.

Also: the Alembic schema (a newer database is refused; old ``schema_version`` files are adopted and upgraded),
``assembly-agent db upgrade``, the ``--database`` forms and the learner-results store.
"""

from __future__ import annotations

import sqlite3
import threading

import pytest
import sqlalchemy as sa
from postgres_server import free_port

from app.auth import TeacherAuth, hash_password, verify_password
from app.cli import main
from app.database import DatabaseTarget
from app.settings import Settings
from app.storage import Storage, StorageError, head_revision

TASK = {"source_sentence": "Μου αρέσει ο καφές", "words": ["Me", "gusta", "el", "café"], "distractors": ["leche"]}

OLD_SCHEMA = [  # what the program wrote before Alembic (schema_version 1), verbatim
    "CREATE TABLE schema_version (version INTEGER NOT NULL)",
    "CREATE TABLE tasks (id INTEGER PRIMARY KEY AUTOINCREMENT, data TEXT NOT NULL, "
    "created_at REAL NOT NULL, updated_at REAL NOT NULL)",
    "CREATE TABLE secrets (key TEXT PRIMARY KEY, value TEXT NOT NULL)",
    "CREATE TABLE sessions (id INTEGER PRIMARY KEY AUTOINCREMENT, started_at REAL NOT NULL, "
    "ended_at REAL, source TEXT NOT NULL, mode TEXT, task TEXT, frames INTEGER NOT NULL DEFAULT 0)",
]


def engine_for(database: str) -> sa.Engine:
    target = DatabaseTarget.parse(database)
    return sa.create_engine(target.url if target.url is not None else f"sqlite:///{target.path}")


def test_tasks_survive_reopen(database):
    s = Storage(database)
    rec = s.create_task(TASK)
    s2 = Storage(database)  # a restart: a new Storage on the same database
    got = s2.get_task(rec["id"])
    assert got["data"] == TASK
    assert s2.update_task(rec["id"], {**TASK, "words": ["Me", "gusta", "la", "leche"]})["data"]["words"][2] == "la"
    assert [t["id"] for t in Storage(database).list_tasks()] == [rec["id"]]
    assert s2.delete_task(rec["id"]) is True
    assert s2.delete_task(rec["id"]) is False
    assert Storage(database).list_tasks() == []
    assert s2.update_task(99, TASK) is None


def test_schema_at_head_and_newer_database_refused(database):
    assert Storage(database).schema_version() == head_revision()
    with engine_for(database).begin() as con:
        con.execute(sa.text("UPDATE alembic_version SET version_num = '9999_future'"))
    with pytest.raises(StorageError, match="newer than this program"):
        Storage(database)
    assert main(["db", "--database", database, "upgrade"]) == 1  # the command refuses it as well


def test_db_upgrade_and_check_commands(database, capsys):
    assert main(["db", "--database", database, "upgrade"]) == 0
    assert f"schema at revision {head_revision()} (was empty)" in capsys.readouterr().out
    assert main(["db", "--database", database, "upgrade"]) == 0  # nothing left to do
    assert capsys.readouterr().out.strip().endswith(f"schema at revision {head_revision()}")
    Storage(database).create_task(TASK)
    assert main(["db", "--database", database, "check"]) == 0
    out = capsys.readouterr().out
    assert "1 teacher task(s), 0 session(s)" in out and ("intact" in out or "reachable" in out)


def test_migrations_go_down_and_up_again(database):
    """Every revision's downgrade undoes its upgrade (on this backend): down to the baseline, then up again."""
    from alembic import command

    from app.storage import BASELINE_REVISION, alembic_config

    Storage(database)
    engine = engine_for(database)
    with engine.begin() as con:
        command.downgrade(alembic_config(con), BASELINE_REVISION)
    with engine.connect() as con:
        assert not sa.inspect(con).has_table("session_steps")
        assert "station" not in {c["name"] for c in sa.inspect(con).get_columns("sessions")}
    s = Storage(database)  # opening upgrades again
    assert s.schema_version() == head_revision()
    sid = s.start_session("sim:static", "guidance", None, station="bench-1")
    assert s.results(station="bench-1")["sessions"][0]["id"] == sid
    engine.dispose()


def test_two_servers_migrate_one_new_database_together(database):
    """Two servers starting at the same moment on an empty database: the schema is created once, both work."""
    opened: list[Storage] = []
    errors: list[BaseException] = []

    def open_one() -> None:
        try:
            opened.append(Storage(database))
        except BaseException as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=open_one) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == [] and len(opened) == 2
    a, b = opened
    rec = a.create_task(TASK)
    assert b.get_task(rec["id"])["data"] == TASK
    assert b.schema_version() == head_revision()


def test_old_schema_version_file_is_adopted(tmp_path, capsys):
    db = tmp_path / "old.sqlite3"
    con = sqlite3.connect(db)
    with con:
        for stmt in OLD_SCHEMA:
            con.execute(stmt)
        con.execute("INSERT INTO schema_version (version) VALUES (1)")
        con.execute("INSERT INTO tasks (data, created_at, updated_at) VALUES ('{\"words\": [\"Hola\"]}', 1.0, 2.0)")
        con.execute("INSERT INTO secrets (key, value) VALUES ('teacher_password', 'scrypt$x')")
        con.execute("INSERT INTO sessions (started_at, ended_at, source, mode, task, frames) "
                    "VALUES (5.0, 9.0, 'sim:static', 'guidance', NULL, 42)")
    con.close()
    assert main(["db", "--database", str(db), "upgrade"]) == 0
    out = capsys.readouterr().out
    assert f"revision {head_revision()}" in out and "(was 0001)" in out
    s = Storage(db)
    assert s.schema_version() == head_revision()
    assert s.list_tasks()[0]["data"] == {"words": ["Hola"]}  # nothing lost
    assert s.get_secret("teacher_password") == "scrypt$x"
    old = s.list_sessions()[0]
    assert (old["frames"], old["source"], old["started_at"]) == (42, "sim:static", 5.0)
    # the new columns exist and work on the adopted file
    sid = s.start_session("sim:static", "guidance", "guidance-5-cubes", station="bench-3")
    assert s.results(station="bench-3")["sessions"][0]["id"] == sid
    # an older program reads only schema_version: it sees a version it does not know and refuses the file
    con = sqlite3.connect(db)
    assert con.execute("SELECT MAX(version) FROM schema_version").fetchone()[0] > 1
    con.close()


def test_old_file_of_a_newer_old_program_refused(tmp_path):
    db = tmp_path / "old.sqlite3"
    con = sqlite3.connect(db)
    with con:
        for stmt in OLD_SCHEMA:
            con.execute(stmt)
        con.execute("INSERT INTO schema_version (version) VALUES (2)")
    con.close()
    with pytest.raises(StorageError, match="schema version 2, newer than this program"):
        Storage(db)


def test_not_a_database_gives_clear_error(tmp_path):
    bad = tmp_path / "junk.sqlite3"
    bad.write_bytes(b"this is not sqlite" * 100)
    with pytest.raises(StorageError, match="junk.sqlite3"):
        Storage(bad)


def test_database_url_forms():
    assert str(Settings(database="sqlite:///tmp/x.db").database_path()) == "tmp/x.db"
    assert str(Settings(database="sqlite:////abs/x.db").database_path()) == "/abs/x.db"
    assert str(Settings(database="data/a.sqlite3").database_path()) == "data/a.sqlite3"
    for url in ("postgresql://u:secret@h:5433/db", "postgres://u:secret@h:5433/db",
                "postgresql+psycopg://u:secret@h:5433/db"):
        target = Settings(database=url).database_target()
        assert target.kind == "postgresql" and target.url.drivername == "postgresql+psycopg"
        assert (target.url.host, target.url.port, target.url.database) == ("h", 5433, "db")
        assert "secret" not in target.display and target.display.startswith("postgresql://u:")
        with pytest.raises(ValueError, match="pg_dump"):
            Settings(database=url).database_path()
    with pytest.raises(ValueError, match="'mysql' databases are not supported"):
        Settings(database="mysql://u@h/db").database_target()
    with pytest.raises(ValueError, match="names no database"):
        Settings(database="postgresql://u@h").database_target()


def test_unreachable_postgres_is_a_clear_error():
    port = free_port()  # nothing listens there
    with pytest.raises(StorageError, match=rf"127\.0\.0\.1:{port}/db is unavailable"):
        Storage(f"postgresql://someone:pw@127.0.0.1:{port}/db")
    assert main(["serve", "--database", f"postgresql://someone:pw@127.0.0.1:{port}/db", "--viser-port", "0",
                 "--port", "0"]) == 1


def test_sessions_listed_newest_first(database):
    s = Storage(database)
    a = s.start_session("sim:static", "guidance", None)
    b = s.start_session("sim:guess-1", "guess", "guess-structures")
    s.end_session(a, 42)
    rows = s.list_sessions()
    assert [r["id"] for r in rows] == [b, a]
    assert rows[1]["frames"] == 42 and rows[1]["ended_at"] is not None


def test_results_stored_and_filtered(database):
    s = Storage(database)
    a = s.start_session("sim:guidance-demo", "guidance", "guidance-5-cubes", station="bench-1")
    b = s.switch_session(a, 10, "sim:guidance-demo", "guidance", "guidance-5-cubes", station="bench-2")
    c = s.start_session("sim:guess-1", "guess", "guess-structures", station="bench-1")
    s.start_session("sim:static", "none", None, station="bench-1")  # tracking only: no learner results
    step = {"attempt": 1, "label": "place red", "verdict": "done", "started_at": 100.0, "ended_at": 104.5,
            "duration_s": 4.5, "wrong_placements": 1, "hints": 0}
    s.record_results([{**step, "session_id": a, "step": 1}, {**step, "session_id": a, "step": 2, "hints": 2}],
                     {a: {"steps_total": 4, "wrong_placements": 1, "hints": 2}})
    s.record_results([], {a: {"wrong_placements": 2, "completed_at": 120.0}})  # increments add up
    s.record_results([], {a: {"completed_at": 130.0}})  # the first completion time is kept
    s.record_results([{**step, "session_id": b, "step": 1, "verdict": "unfinished"}], {b: {"steps_total": 4}})
    by_task = s.results(task="guidance-5-cubes")["sessions"]
    assert [x["id"] for x in by_task] == [b, a]
    sa_ = by_task[1]
    assert (sa_["station"], sa_["steps_total"], sa_["wrong_placements"], sa_["hints"]) == ("bench-1", 4, 3, 2)
    assert sa_["completed_at"] == 120.0
    assert [(x["step"], x["hints"], x["duration_s"]) for x in sa_["steps"]] == [(1, 0, 4.5), (2, 2, 4.5)]
    assert by_task[0]["steps"][0]["verdict"] == "unfinished" and by_task[0]["completed_at"] is None
    assert [x["id"] for x in s.results(station="bench-1")["sessions"]] == [c, a]
    assert s.results(task="nope")["sessions"] == []


def test_password_hash_is_salted_and_not_plaintext(database):
    h1, h2 = hash_password("secret-pw"), hash_password("secret-pw")
    assert h1 != h2 and "secret-pw" not in h1
    assert verify_password("secret-pw", h1) and not verify_password("wrong", h1)
    assert not verify_password("secret-pw", "garbage")
    s = Storage(database)
    auth = TeacherAuth(s)
    assert not auth.is_configured
    with pytest.raises(ValueError, match="at least"):
        auth.setup("ab")
    auth.setup("lehrer-1234")
    with pytest.raises(PermissionError):
        auth.setup("another-password")
    stored = s.get_secret("teacher_password")
    assert "lehrer-1234" not in stored and stored.startswith("scrypt$")
    if s.path is not None:
        assert b"lehrer-1234" not in s.path.read_bytes()
    assert auth.login("nope") is None
    token = auth.login("lehrer-1234")
    assert auth.check_token(token) and not auth.check_token("forged")
    auth.logout(token)
    assert not auth.check_token(token)


def test_env_password_replaces_stored_one(database):
    s = Storage(database)
    TeacherAuth(s).setup("first-password")
    auth = TeacherAuth(s, env_password="from-the-env")
    assert auth.check_password("from-the-env") and not auth.check_password("first-password")


def test_wrong_postgres_settings_are_not_an_outage(postgres_server):
    """An unknown database or user is a setting to correct: said so, and not waited for like an outage."""
    from app.storage import StorageUnavailable, open_storage

    for url, what in ((postgres_server.url("no_such_db"), "no_such_db"),
                      (postgres_server.url("postgres").replace("postgres@", "nobody@"), "nobody")):
        with pytest.raises(StorageError, match=f"refused the connection.*{what}.*does not exist.*createdb") as err:
            open_storage(url, wait_s=60)  # returns at once: nothing to wait for
        assert not isinstance(err.value, StorageUnavailable)
