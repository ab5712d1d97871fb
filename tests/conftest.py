"""Shared fixtures: ``database`` runs a test once on SQLite and once on a real PostgreSQL server.

The PostgreSQL server (:mod:`postgres_server`) is started once per test run, on first use; each test gets a
new empty database in it. Where the server programs are not installed, the PostgreSQL half is skipped and
says why (``pytest -ra`` lists the reason).
"""

from __future__ import annotations

import pytest
from postgres_server import NOT_INSTALLED, PostgresServer, find_bin_dir


@pytest.fixture(scope="session")
def postgres_server():
    """A running PostgreSQL server (skips the test where the Debian package is not installed)."""
    bin_dir = find_bin_dir()
    if bin_dir is None:
        pytest.skip(NOT_INSTALLED)
    server = PostgresServer(bin_dir)
    try:
        server.start()
        yield server
    finally:
        server.destroy()


@pytest.fixture(params=["sqlite", "postgresql"])
def database(request, tmp_path) -> str:
    """``--database`` for a new empty database: a SQLite file, or a database on :func:`postgres_server`."""
    if request.param == "sqlite":
        return str(tmp_path / "agent.sqlite3")
    return request.getfixturevalue("postgres_server").new_database()
