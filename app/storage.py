"""Storage of teacher sentence tasks, sessions with learner results, and server secrets (the hashed teacher
password), through SQLAlchemy 2 on a SQLite file (default) or a PostgreSQL server (psycopg 3).

The schema is managed by Alembic (:mod:`app.migrations`): :meth:`Storage.migrate` (run at start, and by
``assembly-agent db upgrade``) applies the missing revisions and refuses a database written by a newer
program. SQLite files of the old ``schema_version`` scheme are adopted: stamped with the baseline revision,
then upgraded. Tasks are stored as JSON documents (validated before they get here). Times are wall-clock
seconds since the epoch (``time.time()``).

Every operation is one transaction, applied whole or not at all; every database failure becomes a
:class:`StorageError` whose message names the database and says what to do (the web app answers 503).
A PostgreSQL outage is reported the same way; pooled connections are checked before use (``pool_pre_ping``),
so the first operation after the server is back works again without a restart.
"""

from __future__ import annotations

import json
import logging
import os
import sqlite3
import threading
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import sqlalchemy as sa
from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy.engine import Connection, Engine
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.pool import NullPool

from app.database import DatabaseTarget

log = logging.getLogger(__name__)
MIGRATIONS_DIR = Path(__file__).resolve().parent / "migrations"
BASELINE_REVISION = "0001"
"""The revision that matches a file of the old ``schema_version`` scheme (version 1)."""
LEGACY_SCHEMA_VERSION = 1
"""The last version of the old scheme; a file with a higher one comes from a newer program."""
ADVISORY_LOCK_KEY = 0x4153_4D42
"""PostgreSQL advisory lock held while migrating, so two servers starting together do not both migrate."""

metadata = sa.MetaData()
tasks_table = sa.Table(
    "tasks",
    metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("data", sa.Text, nullable=False),
    sa.Column("created_at", sa.Float, nullable=False),
    sa.Column("updated_at", sa.Float, nullable=False),
)
secrets_table = sa.Table(
    "secrets", metadata, sa.Column("key", sa.Text, primary_key=True), sa.Column("value", sa.Text, nullable=False)
)
sessions_table = sa.Table(
    "sessions",
    metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("started_at", sa.Float, nullable=False),
    sa.Column("ended_at", sa.Float),
    sa.Column("source", sa.Text, nullable=False),
    sa.Column("mode", sa.Text),
    sa.Column("task", sa.Text),
    sa.Column("frames", sa.Integer, nullable=False),
    sa.Column("station", sa.Text),
    sa.Column("steps_total", sa.Integer),
    sa.Column("completed_at", sa.Float),
    sa.Column("wrong_placements", sa.Integer, nullable=False),
    sa.Column("hints", sa.Integer, nullable=False),
)
steps_table = sa.Table(
    "session_steps",
    metadata,
    sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
    sa.Column("session_id", sa.Integer, nullable=False),
    sa.Column("attempt", sa.Integer, nullable=False),
    sa.Column("step", sa.Integer, nullable=False),
    sa.Column("label", sa.Text),
    sa.Column("verdict", sa.Text, nullable=False),
    sa.Column("started_at", sa.Float, nullable=False),
    sa.Column("ended_at", sa.Float, nullable=False),
    sa.Column("duration_s", sa.Float, nullable=False),
    sa.Column("wrong_placements", sa.Integer, nullable=False),
    sa.Column("hints", sa.Integer, nullable=False),
)
SESSION_KEYS = ("id", "started_at", "ended_at", "source", "mode", "task", "frames")
RESULT_SESSION_KEYS = (*SESSION_KEYS, "station", "steps_total", "completed_at", "wrong_placements", "hints")
STEP_KEYS = ("session_id", "attempt", "step", "label", "verdict", "started_at", "ended_at", "duration_s",
             "wrong_placements", "hints")


class StorageError(RuntimeError):
    """The database cannot be used: unopenable, damaged, deleted, read-only, unreachable, or from a newer program.

    The message names the database and says what to do; the web app answers it with ``503``."""


class StorageUnavailable(StorageError):
    """The database server cannot be reached (PostgreSQL down or restarting); it may work again by itself."""


UNAVAILABLE = (sa.exc.OperationalError, sa.exc.InterfaceError, sa.exc.TimeoutError)
"""SQLAlchemy errors that mean "the server is not there" on PostgreSQL (refused, cut, pool timed out)."""

RESTORE_HINT = "restore a backup with `assembly-agent db restore BACKUP` or move the file away to start empty"


def alembic_config(connection: Connection | None = None) -> Config:
    """Alembic's configuration in code (no alembic.ini): the migrations folder and the connection to use."""
    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS_DIR))
    if connection is not None:
        cfg.attributes["connection"] = connection
    return cfg


def head_revision() -> str:
    """The newest schema revision this program knows."""
    head = ScriptDirectory.from_config(alembic_config()).get_current_head()
    assert head is not None
    return head


def known_revisions() -> set[str]:
    return {s.revision for s in ScriptDirectory.from_config(alembic_config()).walk_revisions()}


def integrity_problem(path: Path) -> str | None:
    """Why the SQLite file at ``path`` is damaged (``PRAGMA quick_check``), or ``None`` when it reads fine."""
    try:
        con = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, timeout=10.0)
    except sqlite3.Error as exc:
        return str(exc)
    try:
        rows = [str(r[0]) for r in con.execute("PRAGMA quick_check").fetchall()]
    except sqlite3.Error as exc:
        return str(exc)
    finally:
        con.close()
    if rows == ["ok"]:
        return None
    return "; ".join(rows[:3]) + (f" (and {len(rows) - 3} more)" if len(rows) > 3 else "")


LOGIN_PROBLEMS = (
    ("password", "check the user and its password (in the URL, PGPASSWORD or ~/.pgpass)"),
    ("authentication", "check the user and its password (in the URL, PGPASSWORD or ~/.pgpass)"),
    ("does not exist", "create it on the PostgreSQL server (createuser / createdb) or correct the URL"),
    ("permission denied", "grant the user access to the database (its owner: createdb -O USER)"),
)
"""Connection failures that are settings to correct, not an outage: (text in the message, what to do)."""


def _login_problem(exc: BaseException) -> str | None:
    """What to do when ``exc`` is a refused login (wrong password, unknown user or database), else ``None``."""
    text = _first_line(exc).lower()
    return next((hint for key, hint in LOGIN_PROBLEMS if key in text), None)


def _first_line(exc: BaseException) -> str:
    orig = getattr(exc, "orig", None) or exc
    text = str(orig).strip().splitlines()
    return text[0] if text else type(orig).__name__


class Storage:
    """Tasks, sessions, learner results and secrets in one database (:class:`app.database.DatabaseTarget`).

    SQLite: the file and its folder are created if missing (WAL journal), and every operation opens its own
    connection. At start the file is checked (``PRAGMA quick_check``, writable). A damaged or unwritable file
    either stops the program with a :class:`StorageError` naming it (``on_damaged="refuse"``) or is served
    read-only (``on_damaged="read-only"``: :attr:`read_only` holds the reason, every write raises). Once open,
    the file is never created again: a file deleted while the server runs is reported, not silently replaced.

    PostgreSQL: a pool of connections, each checked before use; an unreachable server at start is a
    :class:`StorageError`, during operation each failing call is one (503) until the server is back.
    """

    def __init__(self, database: str | Path | DatabaseTarget, on_damaged: str = "refuse") -> None:
        if on_damaged not in ("refuse", "read-only"):
            raise ValueError(f"on_damaged: expected 'refuse' or 'read-only', got {on_damaged!r}")
        self.target = database if isinstance(database, DatabaseTarget) else DatabaseTarget.parse(database)
        self.path: Path | None = self.target.path
        """The SQLite file (``None`` on PostgreSQL)."""
        self.name = self.target.display
        self._lock = threading.Lock()
        self.read_only: str | None = None
        """Why the database is served read-only (``None``: writable)."""
        self.problem: str | None = None
        """The last storage error while serving (``None`` after a successful operation)."""
        self.timeout = 10.0
        """Seconds to wait for a lock held by another connection (SQLite) or for a connection (PostgreSQL)."""
        self._may_create = False
        if self.path is not None:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise StorageError(f"database {self.path}: cannot create its folder: {exc}") from exc
            self.engine: Engine = sa.create_engine("sqlite://", creator=self._sqlite_connect, poolclass=NullPool)
            # SQLAlchemy's recipe for whole transactions on SQLite (DDL included, so a migration is applied whole
            # or not at all): the driver's own transaction handling is off and BEGIN is sent here; a migration
            # takes the write lock at once (BEGIN IMMEDIATE), so two servers starting together migrate in turn.
            sa.event.listen(
                self.engine,
                "begin",
                lambda con: con.exec_driver_sql("BEGIN IMMEDIATE" if self._may_create else "BEGIN"),
            )
            reason = self._start_problem()
            if reason is not None:
                if on_damaged == "refuse":
                    raise StorageError(f"database {self.path}: {reason}; {RESTORE_HINT}")
                self.read_only = f"database {self.path} is served read-only: {reason}; {RESTORE_HINT}"
                self.migration = None
                return
        else:
            self.engine = sa.create_engine(
                self.target.url,
                pool_pre_ping=True,  # a connection that died with the server is replaced, not used
                pool_size=4,
                max_overflow=4,
                pool_timeout=self.timeout,
                connect_args={"connect_timeout": 5},
            )
        self.migration: tuple[str | None, str] | None = self.migrate()
        """(revision before, revision after) of the migration applied when opening (``None``: read-only)."""

    # ------------------------------------------------------------------ connections
    @property
    def is_sqlite(self) -> bool:
        return self.path is not None

    def _sqlite_connect(self) -> sqlite3.Connection:
        assert self.path is not None
        mode = "ro" if self.read_only else ("rwc" if self._may_create else "rw")
        con = sqlite3.connect(
            f"{self.path.resolve().as_uri()}?mode={mode}", uri=True, timeout=self.timeout, check_same_thread=False,
            isolation_level=None,
        )
        if self._may_create:
            # kept by the file; outside a transaction, as SQLite needs. Switching a new file to WAL takes an exclusive
            # lock: a second server migrating the same new file at that moment makes SQLite report "locked" at once
            # (a lock deadlock, which the busy timeout does not wait out), so it is tried again until the timeout.
            deadline = time.monotonic() + self.timeout
            while True:
                try:
                    con.execute("PRAGMA journal_mode=WAL")
                    break
                except sqlite3.OperationalError as exc:
                    if "locked" not in str(exc) or time.monotonic() > deadline:
                        con.close()
                        raise
                    time.sleep(0.05)
                except sqlite3.Error:
                    con.close()
                    raise
        return con

    def _start_problem(self) -> str | None:
        """Why the existing file cannot be used for writing (damaged, not a database, not writable), or None."""
        assert self.path is not None
        if not self.path.exists():
            return None
        damage = integrity_problem(self.path)
        if damage is not None:
            return f"the file is damaged ({damage})"
        if not os.access(self.path, os.W_OK) or not os.access(self.path.parent, os.W_OK):
            return "the file (or its folder) is not writable"
        return None

    @contextmanager
    def _transaction(self) -> Iterator[Connection]:
        """A connection in one transaction (committed on success, rolled back on error); errors are StorageError."""
        try:
            with self.engine.begin() as con:
                yield con
        except SQLAlchemyError as exc:
            error = self._failed(self._explain(exc))
            if self.path is None and isinstance(exc, UNAVAILABLE) and _login_problem(exc) is None:
                error = StorageUnavailable(str(error))
            raise error from exc
        self.problem = None

    def _explain(self, exc: SQLAlchemyError) -> str:
        """The message for a failed operation: which database, what happened, what to do."""
        if self.path is not None:
            if not self.path.exists():
                return (
                    f"database {self.path} is missing (deleted while the server ran?): nothing can be read or "
                    f"saved; {RESTORE_HINT} and restart the server"
                )
            return f"database {self.path}: {_first_line(exc)}"
        hint = _login_problem(exc)
        if hint is not None:
            return f"database {self.name} refused the connection ({_first_line(exc)}); {hint}"
        if isinstance(exc, UNAVAILABLE):
            return (
                f"database {self.name} is unavailable ({_first_line(exc)}); nothing was changed. The server "
                "keeps trying and works again as soon as the database is back"
            )
        return f"database {self.name}: {_first_line(exc)}"

    def _failed(self, message: str) -> StorageError:
        self.problem = message
        return StorageError(message)

    def _writable(self) -> None:
        if self.read_only:
            raise StorageError(f"{self.read_only} (changes are refused)")

    def dispose(self) -> None:
        """Close the pooled connections (PostgreSQL); the storage reconnects when used again."""
        self.engine.dispose()

    # ------------------------------------------------------------------ schema
    def schema_version(self) -> str | None:
        """The applied Alembic revision (``None`` for an empty database)."""
        with self._transaction() as con:
            return MigrationContext.configure(con).get_current_revision()

    def migrate(self) -> tuple[str | None, str]:
        """Apply missing migrations; returns (revision before, revision after). Refuses a newer database.

        A SQLite file of the old ``schema_version`` scheme is adopted (stamped with the baseline revision) first.
        """
        head = head_revision()
        with self._lock:
            self._may_create = True
            try:
                with self._transaction() as con:
                    if not self.is_sqlite:  # one migrating server at a time; the lock ends with the transaction
                        con.execute(sa.text("SELECT pg_advisory_xact_lock(:k)"), {"k": ADVISORY_LOCK_KEY})
                    before = MigrationContext.configure(con).get_current_revision()
                    if before is None:
                        legacy = self._legacy_version(con)
                        if legacy is not None and legacy > LEGACY_SCHEMA_VERSION:
                            raise StorageError(
                                f"database {self.name} has schema version {legacy}, newer than this program's; "
                                "upgrade assembly-agent or use another database"
                            )
                        if legacy == LEGACY_SCHEMA_VERSION:
                            command.stamp(alembic_config(con), BASELINE_REVISION)
                            before = BASELINE_REVISION
                    elif before not in known_revisions():
                        raise StorageError(
                            f"database {self.name} has schema revision {before!r}, newer than this program's "
                            f"{head!r}; upgrade assembly-agent or use another database"
                        )
                    if before != head:
                        command.upgrade(alembic_config(con), "head")
            except StorageError as exc:
                if self.is_sqlite and "newer than" not in str(exc):
                    raise StorageError(f"{exc} (not a usable SQLite file?)") from exc
                raise
            finally:
                self._may_create = False
        return before, head

    @staticmethod
    def _legacy_version(con: Connection) -> int | None:
        """The old scheme's ``MAX(version)`` when its table exists with tables in it, else ``None``."""
        inspector = sa.inspect(con)
        if not inspector.has_table("schema_version") or not inspector.has_table("tasks"):
            return None
        return int(con.execute(sa.text("SELECT MAX(version) FROM schema_version")).scalar() or 0)

    def counts(self) -> dict[str, int]:
        """How many tasks, sessions and result steps the database holds."""
        with self._transaction() as con:
            return {
                name: int(con.execute(sa.select(sa.func.count()).select_from(table)).scalar_one())
                for name, table in (("tasks", tasks_table), ("sessions", sessions_table), ("steps", steps_table))
            }

    def status(self) -> dict[str, Any]:
        """``{path, read_only, problem}`` for ``/api/status`` (path: the file, or the URL without password)."""
        problem = self.read_only or self.problem
        if problem is None and self.path is not None and not self.path.exists():
            problem = f"database {self.path} is missing (deleted while the server ran?); {RESTORE_HINT} and restart"
        return {"path": self.name, "read_only": self.read_only is not None, "problem": problem}

    # ------------------------------------------------------------------ tasks
    @staticmethod
    def _row_to_task(row: Sequence) -> dict[str, Any]:
        return {"id": int(row[0]), "data": json.loads(row[1]), "created_at": row[2], "updated_at": row[3]}

    def list_tasks(self) -> list[dict[str, Any]]:
        t = tasks_table
        with self._transaction() as con:
            rows = con.execute(sa.select(t.c.id, t.c.data, t.c.created_at, t.c.updated_at).order_by(t.c.id)).all()
        return [self._row_to_task(r) for r in rows]

    def get_task(self, task_id: int) -> dict[str, Any] | None:
        t = tasks_table
        with self._transaction() as con:
            row = con.execute(
                sa.select(t.c.id, t.c.data, t.c.created_at, t.c.updated_at).where(t.c.id == int(task_id))
            ).first()
        return None if row is None else self._row_to_task(row)

    def create_task(self, data: dict[str, Any]) -> dict[str, Any]:
        self._writable()
        now = time.time()
        with self._transaction() as con:
            task_id = con.execute(
                sa.insert(tasks_table)
                .values(data=json.dumps(data, ensure_ascii=False), created_at=now, updated_at=now)
                .returning(tasks_table.c.id)
            ).scalar_one()
        return {"id": int(task_id), "data": data, "created_at": now, "updated_at": now}

    def update_task(self, task_id: int, data: dict[str, Any]) -> dict[str, Any] | None:
        self._writable()
        now = time.time()
        with self._transaction() as con:
            cur = con.execute(
                sa.update(tasks_table)
                .where(tasks_table.c.id == int(task_id))
                .values(data=json.dumps(data, ensure_ascii=False), updated_at=now)
            )
            if cur.rowcount == 0:
                return None
        return self.get_task(task_id)

    def delete_task(self, task_id: int) -> bool:
        self._writable()
        with self._transaction() as con:
            cur = con.execute(sa.delete(tasks_table).where(tasks_table.c.id == int(task_id)))
        return cur.rowcount > 0

    # ------------------------------------------------------------------ secrets
    def get_secret(self, key: str) -> str | None:
        with self._transaction() as con:
            value = con.execute(sa.select(secrets_table.c.value).where(secrets_table.c.key == key)).scalar()
        return None if value is None else str(value)

    def set_secret(self, key: str, value: str) -> None:
        self._writable()
        with self._transaction() as con:
            updated = con.execute(sa.update(secrets_table).where(secrets_table.c.key == key).values(value=value))
            if updated.rowcount == 0:
                con.execute(sa.insert(secrets_table).values(key=key, value=value))

    # ------------------------------------------------------------------ sessions
    @staticmethod
    def _insert_session(con: Connection, now: float, source: str, mode: str | None, task: str | None,
                        station: str | None) -> int:
        return int(
            con.execute(
                sa.insert(sessions_table)
                .values(started_at=now, source=source, mode=mode, task=task, station=station, frames=0,
                        wrong_placements=0, hints=0)
                .returning(sessions_table.c.id)
            ).scalar_one()
        )

    def start_session(self, source: str, mode: str | None, task: str | None, station: str | None = None) -> int:
        self._writable()
        with self._transaction() as con:
            return self._insert_session(con, time.time(), source, mode, task, station)

    def switch_session(
        self, old_id: int | None, old_frames: int, source: str, mode: str | None, task: str | None,
        station: str | None = None,
    ) -> int:
        """End session ``old_id`` (if any) with ``old_frames`` and start a new one, in one transaction."""
        self._writable()
        now = time.time()
        s = sessions_table
        with self._transaction() as con:
            if old_id is not None:
                con.execute(sa.update(s).where(s.c.id == old_id).values(ended_at=now, frames=int(old_frames)))
            return self._insert_session(con, now, source, mode, task, station)

    def end_session(self, session_id: int, frames: int) -> None:
        self._writable()
        s = sessions_table
        with self._transaction() as con:
            con.execute(sa.update(s).where(s.c.id == session_id).values(ended_at=time.time(), frames=int(frames)))

    def update_session_frames(self, session_id: int, frames: int) -> None:
        self._writable()
        s = sessions_table
        with self._transaction() as con:
            con.execute(sa.update(s).where(s.c.id == session_id).values(frames=int(frames)))

    def list_sessions(self, limit: int = 50) -> list[dict[str, Any]]:
        s = sessions_table
        with self._transaction() as con:
            rows = con.execute(
                sa.select(*(s.c[k] for k in SESSION_KEYS)).order_by(s.c.id.desc()).limit(int(limit))
            ).all()
        return [dict(zip(SESSION_KEYS, r, strict=True)) for r in rows]

    # ------------------------------------------------------------------ learner results
    def record_results(self, steps: Sequence[dict[str, Any]], totals: dict[int, dict[str, Any]]) -> None:
        """Store step rows (keys :data:`STEP_KEYS`) and per-session totals in one transaction.

        ``totals`` maps a session id to the values to set: ``steps_total``, ``completed_at`` and the increments
        ``wrong_placements`` / ``hints`` (added to the stored counts, so batches can be written as they come)."""
        self._writable()
        s = sessions_table
        with self._transaction() as con:
            if steps:
                con.execute(sa.insert(steps_table), [{k: row[k] for k in STEP_KEYS} for row in steps])
            for session_id, tot in totals.items():
                values: dict[str, Any] = {
                    "wrong_placements": s.c.wrong_placements + int(tot.get("wrong_placements", 0)),
                    "hints": s.c.hints + int(tot.get("hints", 0)),
                }
                if tot.get("steps_total") is not None:
                    values["steps_total"] = int(tot["steps_total"])
                if tot.get("completed_at") is not None:
                    values["completed_at"] = sa.func.coalesce(s.c.completed_at, float(tot["completed_at"]))
                con.execute(sa.update(s).where(s.c.id == int(session_id)).values(**values))

    def results(self, task: str | None = None, station: str | None = None, limit: int = 500) -> dict[str, Any]:
        """Sessions that have a mode (newest first, at most ``limit``), each with its step rows, filtered by task
        and station: ``{"sessions": [{…, "steps": [{…}]}]}``."""
        s, st = sessions_table, steps_table
        query = sa.select(*(s.c[k] for k in RESULT_SESSION_KEYS)).where(s.c.mode.is_not(None), s.c.mode != "none")
        if task is not None:
            query = query.where(s.c.task == task)
        if station is not None:
            query = query.where(s.c.station == station)
        with self._transaction() as con:
            rows = con.execute(query.order_by(s.c.id.desc()).limit(int(limit))).all()
            sessions = [dict(zip(RESULT_SESSION_KEYS, r, strict=True)) for r in rows]
            ids = [x["id"] for x in sessions]
            step_rows = []
            if ids:
                step_rows = con.execute(
                    sa.select(*(st.c[k] for k in STEP_KEYS))
                    .where(st.c.session_id.in_(ids))
                    .order_by(st.c.session_id, st.c.attempt, st.c.step, st.c.id)
                ).all()
        by_session: dict[int, list[dict[str, Any]]] = {i: [] for i in ids}
        for r in step_rows:
            d = dict(zip(STEP_KEYS, r, strict=True))
            by_session[d["session_id"]].append(d)
        for x in sessions:
            x["steps"] = by_session[x["id"]]
        return {"sessions": sessions}


def open_storage(
    database: str | Path | DatabaseTarget, on_damaged: str = "refuse", wait_s: float = 0.0, poll_s: float = 1.0
) -> Storage:
    """:class:`Storage` on ``database``; while its server is unreachable (:class:`StorageUnavailable`), try again
    every ``poll_s`` seconds for up to ``wait_s`` seconds (a server starting before its database, as in a
    classroom's compose file); then, or on any other error, raise."""
    deadline = time.monotonic() + max(0.0, wait_s)
    while True:
        try:
            return Storage(database, on_damaged=on_damaged)
        except StorageUnavailable as exc:
            left = deadline - time.monotonic()
            if left <= 0:
                raise
            log.warning("%s; trying again for %.0f s more", exc, left)
            time.sleep(min(poll_s, left))


# ---------------------------------------------------------------------- backup and restore
def _sqlite_copy(src: Path, dest: Path) -> None:
    """Copy the database ``src`` into a new file ``dest`` with SQLite's online backup (consistent while in use)."""
    source = sqlite3.connect(f"{src.resolve().as_uri()}?mode=ro", uri=True, timeout=10.0)
    try:
        target = sqlite3.connect(dest)
        try:
            source.backup(target)
            target.execute("PRAGMA journal_mode=DELETE")  # a single self-contained file
        finally:
            target.close()
    finally:
        source.close()


def _describe(path: Path) -> dict[str, Any]:
    """Row counts of a checked database file (tasks, sessions) and its schema revision (``None``: an old file)."""
    con = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)
    try:
        tasks = int(con.execute("SELECT COUNT(*) FROM tasks").fetchone()[0])
        sessions = int(con.execute("SELECT COUNT(*) FROM sessions").fetchone()[0])
        has_alembic = con.execute("SELECT 1 FROM sqlite_master WHERE name = 'alembic_version'").fetchone()
        revision = con.execute("SELECT version_num FROM alembic_version").fetchone() if has_alembic else None
        legacy = int(con.execute("SELECT MAX(version) FROM schema_version").fetchone()[0] or 0)
    finally:
        con.close()
    return {"revision": None if revision is None else str(revision[0]), "legacy_version": legacy, "tasks": tasks,
            "sessions": sessions}


def check_database(path: str | Path) -> dict[str, Any]:
    """Check that ``path`` is an intact database of this program; its counts, or :class:`StorageError`."""
    path = Path(path)
    if not path.is_file():
        raise StorageError(f"database {path}: no such file")
    damage = integrity_problem(path)
    if damage is not None:
        raise StorageError(f"database {path} is damaged ({damage})")
    try:
        info = _describe(path)
    except sqlite3.Error as exc:
        raise StorageError(f"database {path} is not a database of this program ({exc})") from exc
    if info["revision"] is not None and info["revision"] not in known_revisions():
        raise StorageError(f"database {path} has schema revision {info['revision']!r}, newer than {head_revision()!r}")
    if info["revision"] is None and info["legacy_version"] > LEGACY_SCHEMA_VERSION:
        raise StorageError(f"database {path} has schema version {info['legacy_version']}, newer than this program's")
    return info


def backup_database(database: str | Path, backup: str | Path, overwrite: bool = False) -> dict[str, Any]:
    """Write a consistent copy of ``database`` to ``backup`` (safe while the server runs); the copy's counts."""
    database, backup = Path(database), Path(backup)
    check_database(database)
    if backup.exists() and not overwrite:
        raise StorageError(f"backup {backup} exists already; choose another name (or --force)")
    backup.parent.mkdir(parents=True, exist_ok=True)
    tmp = backup.with_name(backup.name + ".partial")
    try:
        _sqlite_copy(database, tmp)
        info = check_database(tmp)
        os.replace(tmp, backup)
    except (sqlite3.Error, OSError) as exc:
        raise StorageError(f"backup of {database} to {backup} failed: {exc}") from exc
    finally:
        tmp.unlink(missing_ok=True)
    return info


def restore_database(backup: str | Path, database: str | Path) -> tuple[dict[str, Any], Path | None]:
    """Replace ``database`` by the checked copy ``backup`` (stop the server first).

    The file it replaces (with its WAL files) is kept beside it as ``<name>.before-restore-<time>``, so a
    restore never loses anything. Returns the restored counts and that kept file (``None`` if there was none)."""
    backup, database = Path(backup), Path(database)
    info = check_database(backup)
    database.parent.mkdir(parents=True, exist_ok=True)
    tmp = database.with_name(database.name + ".restoring")
    kept = None
    try:
        _sqlite_copy(backup, tmp)
        check_database(tmp)
        if database.exists():
            kept = database.with_name(f"{database.name}.before-restore-{time.strftime('%Y%m%d-%H%M%S')}")
            os.replace(database, kept)
        for suffix in ("-wal", "-shm"):  # the old file's journal goes with it (it may hold its newest changes)
            side = database.with_name(database.name + suffix)
            if side.exists():
                aside = kept or database.with_name(f"{database.name}.orphan-{time.strftime('%Y%m%d-%H%M%S')}")
                os.replace(side, aside.with_name(aside.name + suffix))
        os.replace(tmp, database)
    except (sqlite3.Error, OSError) as exc:
        raise StorageError(f"restore of {database} from {backup} failed: {exc}") from exc
    finally:
        tmp.unlink(missing_ok=True)
    return info, kept
