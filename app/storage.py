"""SQLite storage: teacher sentence tasks, sessions and server secrets (the hashed teacher password).

One file (path from settings), opened per operation so any thread may call in. The schema is
versioned: ``schema_version`` holds the applied version and :data:`MIGRATIONS` brings an older file
up to date on open. Tasks are stored as JSON documents (validated before they get here).
"""

from __future__ import annotations

import json
import os
import sqlite3
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

MIGRATIONS: list[list[str]] = [
    # version 1
    [
        "CREATE TABLE tasks (id INTEGER PRIMARY KEY AUTOINCREMENT, data TEXT NOT NULL, "
        "created_at REAL NOT NULL, updated_at REAL NOT NULL)",
        "CREATE TABLE secrets (key TEXT PRIMARY KEY, value TEXT NOT NULL)",
        "CREATE TABLE sessions (id INTEGER PRIMARY KEY AUTOINCREMENT, started_at REAL NOT NULL, "
        "ended_at REAL, source TEXT NOT NULL, mode TEXT, task TEXT, frames INTEGER NOT NULL DEFAULT 0)",
    ],
]
"""SQL statements per schema version (index 0 → version 1). Append new versions; never edit old ones."""

SCHEMA_VERSION = len(MIGRATIONS)


class StorageError(RuntimeError):
    """The database cannot be used: unopenable, damaged, deleted, read-only, or from a newer program.

    The message names the file and says what to do; the web app answers it with ``503``."""


RESTORE_HINT = "restore a backup with `assembly-agent db restore BACKUP` or move the file away to start empty"


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


class Storage:
    """Tasks, sessions and secrets in one SQLite file (WAL journal); the file and its folder are created if missing.

    At start the file is checked (``PRAGMA quick_check``, writable). A damaged or unwritable file either stops
    the program with a :class:`StorageError` naming it (``on_damaged="refuse"``) or is served read-only
    (``on_damaged="read-only"``: :attr:`read_only` holds the reason, every write raises). Once open, the file is
    never created again: a file deleted while the server runs is reported (:class:`StorageError`), not
    silently replaced by an empty one. Every operation is one transaction: it is applied whole or not at all.
    """

    def __init__(self, path: str | Path, on_damaged: str = "refuse") -> None:
        if on_damaged not in ("refuse", "read-only"):
            raise ValueError(f"on_damaged: expected 'refuse' or 'read-only', got {on_damaged!r}")
        self.path = Path(path)
        self._lock = threading.Lock()
        self.read_only: str | None = None
        """Why the database is served read-only (``None``: writable)."""
        self.problem: str | None = None
        """The last storage error while serving (``None`` after a successful operation)."""
        self.timeout = 10.0
        """Seconds to wait for a lock held by another connection before an operation fails."""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StorageError(f"database {self.path}: cannot create its folder: {exc}") from exc
        reason = self._start_problem()
        if reason is not None:
            if on_damaged == "refuse":
                raise StorageError(f"database {self.path}: {reason}; {RESTORE_HINT}")
            self.read_only = f"database {self.path} is served read-only: {reason}; {RESTORE_HINT}"
            return
        self.migrate()

    def _start_problem(self) -> str | None:
        """Why the existing file cannot be used for writing (damaged, not a database, not writable), or None."""
        if not self.path.exists():
            return None
        damage = integrity_problem(self.path)
        if damage is not None:
            return f"the file is damaged ({damage})"
        if not os.access(self.path, os.W_OK) or not os.access(self.path.parent, os.W_OK):
            return "the file (or its folder) is not writable"
        return None

    @contextmanager
    def _connect(self, create: bool = False) -> Iterator[sqlite3.Connection]:
        """A connection in one transaction (committed on success, rolled back on error); errors are StorageError."""
        mode = "ro" if self.read_only else ("rwc" if create else "rw")
        try:
            con = sqlite3.connect(f"{self.path.resolve().as_uri()}?mode={mode}", uri=True, timeout=self.timeout)
        except sqlite3.Error as exc:
            if not self.path.exists():
                raise self._failed(
                    f"database {self.path} is missing (deleted while the server ran?): nothing can be read or "
                    f"saved; {RESTORE_HINT} and restart the server"
                ) from exc
            raise self._failed(f"database {self.path}: {exc}") from exc
        try:
            with con:
                yield con
        except sqlite3.Error as exc:
            raise self._failed(f"database {self.path}: {exc}") from exc
        finally:
            con.close()
        self.problem = None

    def _failed(self, message: str) -> StorageError:
        self.problem = message
        return StorageError(message)

    def _writable(self) -> None:
        if self.read_only:
            raise StorageError(f"{self.read_only} (changes are refused)")

    def schema_version(self) -> int:
        with self._connect() as con:
            row = con.execute("SELECT MAX(version) FROM schema_version").fetchone()
        return int(row[0] or 0)

    def migrate(self) -> int:
        """Apply missing migrations; returns the schema version. Refuses a file from a newer program."""
        with self._lock:
            try:
                with self._connect(create=True) as con:
                    con.execute("PRAGMA journal_mode=WAL")
                    con.execute("CREATE TABLE IF NOT EXISTS schema_version (version INTEGER NOT NULL)")
                    row = con.execute("SELECT MAX(version) FROM schema_version").fetchone()
            except StorageError as exc:
                raise StorageError(f"{exc} (not a usable SQLite file?)") from exc
            current = int(row[0] or 0)
            if current > SCHEMA_VERSION:
                raise StorageError(
                    f"database {self.path} has schema version {current}, newer than this program's "
                    f"{SCHEMA_VERSION}; upgrade assembly-agent or use another database"
                )
            with self._connect() as con:
                for version in range(current + 1, SCHEMA_VERSION + 1):
                    for stmt in MIGRATIONS[version - 1]:
                        con.execute(stmt)
                    con.execute("INSERT INTO schema_version (version) VALUES (?)", (version,))
            return SCHEMA_VERSION

    def status(self) -> dict[str, Any]:
        """``{path, read_only, problem}`` for ``/api/status``."""
        problem = self.read_only or self.problem
        if problem is None and not self.path.exists():
            problem = f"database {self.path} is missing (deleted while the server ran?); {RESTORE_HINT} and restart"
        return {"path": str(self.path), "read_only": self.read_only is not None, "problem": problem}

    # ------------------------------------------------------------------ tasks
    @staticmethod
    def _row_to_task(row: tuple) -> dict[str, Any]:
        return {"id": int(row[0]), "data": json.loads(row[1]), "created_at": row[2], "updated_at": row[3]}

    def list_tasks(self) -> list[dict[str, Any]]:
        with self._connect() as con:
            rows = con.execute("SELECT id, data, created_at, updated_at FROM tasks ORDER BY id").fetchall()
        return [self._row_to_task(r) for r in rows]

    def get_task(self, task_id: int) -> dict[str, Any] | None:
        with self._connect() as con:
            row = con.execute(
                "SELECT id, data, created_at, updated_at FROM tasks WHERE id = ?", (int(task_id),)
            ).fetchone()
        return None if row is None else self._row_to_task(row)

    def create_task(self, data: dict[str, Any]) -> dict[str, Any]:
        self._writable()
        now = time.time()
        with self._connect() as con:
            cur = con.execute(
                "INSERT INTO tasks (data, created_at, updated_at) VALUES (?, ?, ?)",
                (json.dumps(data, ensure_ascii=False), now, now),
            )
            task_id = cur.lastrowid
        return {"id": int(task_id), "data": data, "created_at": now, "updated_at": now}

    def update_task(self, task_id: int, data: dict[str, Any]) -> dict[str, Any] | None:
        self._writable()
        now = time.time()
        with self._connect() as con:
            cur = con.execute(
                "UPDATE tasks SET data = ?, updated_at = ? WHERE id = ?",
                (json.dumps(data, ensure_ascii=False), now, int(task_id)),
            )
            if cur.rowcount == 0:
                return None
        return self.get_task(task_id)

    def delete_task(self, task_id: int) -> bool:
        self._writable()
        with self._connect() as con:
            cur = con.execute("DELETE FROM tasks WHERE id = ?", (int(task_id),))
        return cur.rowcount > 0

    # ------------------------------------------------------------------ secrets
    def get_secret(self, key: str) -> str | None:
        with self._connect() as con:
            row = con.execute("SELECT value FROM secrets WHERE key = ?", (key,)).fetchone()
        return None if row is None else str(row[0])

    def set_secret(self, key: str, value: str) -> None:
        self._writable()
        with self._connect() as con:
            con.execute(
                "INSERT INTO secrets (key, value) VALUES (?, ?) ON CONFLICT(key) DO UPDATE SET value = excluded.value",
                (key, value),
            )

    # ------------------------------------------------------------------ sessions
    def start_session(self, source: str, mode: str | None, task: str | None) -> int:
        self._writable()
        with self._connect() as con:
            cur = con.execute(
                "INSERT INTO sessions (started_at, source, mode, task) VALUES (?, ?, ?, ?)",
                (time.time(), source, mode, task),
            )
            return int(cur.lastrowid)

    def switch_session(
        self, old_id: int | None, old_frames: int, source: str, mode: str | None, task: str | None
    ) -> int:
        """End session ``old_id`` (if any) with ``old_frames`` and start a new one, in one transaction."""
        self._writable()
        now = time.time()
        with self._connect() as con:
            if old_id is not None:
                con.execute("UPDATE sessions SET ended_at = ?, frames = ? WHERE id = ?", (now, int(old_frames), old_id))
            cur = con.execute(
                "INSERT INTO sessions (started_at, source, mode, task) VALUES (?, ?, ?, ?)", (now, source, mode, task)
            )
            return int(cur.lastrowid)

    def end_session(self, session_id: int, frames: int) -> None:
        self._writable()
        with self._connect() as con:
            con.execute(
                "UPDATE sessions SET ended_at = ?, frames = ? WHERE id = ?", (time.time(), int(frames), session_id)
            )

    def update_session_frames(self, session_id: int, frames: int) -> None:
        self._writable()
        with self._connect() as con:
            con.execute("UPDATE sessions SET frames = ? WHERE id = ?", (int(frames), session_id))

    def list_sessions(self, limit: int = 50) -> list[dict[str, Any]]:
        with self._connect() as con:
            rows = con.execute(
                "SELECT id, started_at, ended_at, source, mode, task, frames FROM sessions ORDER BY id DESC LIMIT ?",
                (int(limit),),
            ).fetchall()
        keys = ("id", "started_at", "ended_at", "source", "mode", "task", "frames")
        return [dict(zip(keys, r, strict=True)) for r in rows]


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


def _describe(path: Path) -> dict[str, int]:
    """Row counts of a checked database file (tasks, sessions) and its schema version."""
    con = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True)
    try:
        version = int(con.execute("SELECT MAX(version) FROM schema_version").fetchone()[0] or 0)
        tasks = int(con.execute("SELECT COUNT(*) FROM tasks").fetchone()[0])
        sessions = int(con.execute("SELECT COUNT(*) FROM sessions").fetchone()[0])
    finally:
        con.close()
    return {"schema_version": version, "tasks": tasks, "sessions": sessions}


def check_database(path: str | Path) -> dict[str, int]:
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
    if info["schema_version"] > SCHEMA_VERSION:
        raise StorageError(f"database {path} has schema version {info['schema_version']}, newer than {SCHEMA_VERSION}")
    return info


def backup_database(database: str | Path, backup: str | Path, overwrite: bool = False) -> dict[str, int]:
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


def restore_database(backup: str | Path, database: str | Path) -> tuple[dict[str, int], Path | None]:
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
