"""SQLite storage: teacher sentence tasks, sessions and server secrets (the hashed teacher password).

One file (path from settings), opened per operation so any thread may call in. The schema is
versioned: ``schema_version`` holds the applied version and :data:`MIGRATIONS` brings an older file
up to date on open. Tasks are stored as JSON documents (validated before they get here).
"""

from __future__ import annotations

import json
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
    """The database file cannot be opened or is from a newer version of the program."""


class Storage:
    """Tasks, sessions and secrets in one SQLite file; the file and its folder are created if missing."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StorageError(f"database {self.path}: cannot create its folder: {exc}") from exc
        self.migrate()

    @contextmanager
    def _connect(self) -> Iterator[sqlite3.Connection]:
        try:
            con = sqlite3.connect(self.path, timeout=10.0)
        except sqlite3.Error as exc:
            raise StorageError(f"database {self.path}: {exc}") from exc
        try:
            with con:
                yield con
        finally:
            con.close()

    def schema_version(self) -> int:
        with self._connect() as con:
            con.execute("CREATE TABLE IF NOT EXISTS schema_version (version INTEGER NOT NULL)")
            row = con.execute("SELECT MAX(version) FROM schema_version").fetchone()
        return int(row[0] or 0)

    def migrate(self) -> int:
        """Apply missing migrations; returns the schema version. Refuses a file from a newer program."""
        with self._lock:
            try:
                current = self.schema_version()
            except sqlite3.DatabaseError as exc:
                raise StorageError(f"database {self.path}: not a usable SQLite file ({exc})") from exc
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
        now = time.time()
        with self._connect() as con:
            cur = con.execute(
                "INSERT INTO tasks (data, created_at, updated_at) VALUES (?, ?, ?)",
                (json.dumps(data, ensure_ascii=False), now, now),
            )
            task_id = cur.lastrowid
        return {"id": int(task_id), "data": data, "created_at": now, "updated_at": now}

    def update_task(self, task_id: int, data: dict[str, Any]) -> dict[str, Any] | None:
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
        with self._connect() as con:
            cur = con.execute("DELETE FROM tasks WHERE id = ?", (int(task_id),))
        return cur.rowcount > 0

    # ------------------------------------------------------------------ secrets
    def get_secret(self, key: str) -> str | None:
        with self._connect() as con:
            row = con.execute("SELECT value FROM secrets WHERE key = ?", (key,)).fetchone()
        return None if row is None else str(row[0])

    def set_secret(self, key: str, value: str) -> None:
        with self._connect() as con:
            con.execute(
                "INSERT INTO secrets (key, value) VALUES (?, ?) ON CONFLICT(key) DO UPDATE SET value = excluded.value",
                (key, value),
            )

    # ------------------------------------------------------------------ sessions
    def start_session(self, source: str, mode: str | None, task: str | None) -> int:
        with self._connect() as con:
            cur = con.execute(
                "INSERT INTO sessions (started_at, source, mode, task) VALUES (?, ?, ?, ?)",
                (time.time(), source, mode, task),
            )
            return int(cur.lastrowid)

    def end_session(self, session_id: int, frames: int) -> None:
        with self._connect() as con:
            con.execute(
                "UPDATE sessions SET ended_at = ?, frames = ? WHERE id = ?", (time.time(), int(frames), session_id)
            )

    def update_session_frames(self, session_id: int, frames: int) -> None:
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
