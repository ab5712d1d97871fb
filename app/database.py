"""Where the database lives (:class:`DatabaseTarget`): a SQLite file (the default) or a PostgreSQL server.

Accepted forms of ``--database`` / ``ASSEMBLY_AGENT_DATABASE``:

* a file path (``data/assembly-agent.sqlite3``) or ``sqlite:///relative/path`` / ``sqlite:////absolute/path``;
* ``postgresql://user:password@host:port/dbname`` (also ``postgresql+psycopg://…`` and ``postgres://…``),
  driven by psycopg 3. Query parameters are passed on to libpq (e.g. ``?sslmode=require``).

The password of a PostgreSQL URL is never shown: :attr:`DatabaseTarget.display` hides it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from sqlalchemy.engine import URL, make_url
from sqlalchemy.exc import ArgumentError

POSTGRES_SCHEMES = ("postgresql", "postgresql+psycopg", "postgres")
URL_FORMS = "a SQLite file path, sqlite:///path or postgresql://user@host/dbname"


@dataclass(frozen=True)
class DatabaseTarget:
    """A parsed ``--database``: ``kind`` ``sqlite`` (with :attr:`path`) or ``postgresql`` (with :attr:`url`)."""

    kind: str
    path: Path | None = None
    url: URL | None = None

    @classmethod
    def parse(cls, text: str | Path) -> DatabaseTarget:
        """The target named by ``text``; ValueError naming the accepted forms for anything else."""
        if isinstance(text, Path):
            return cls("sqlite", path=text)
        text = str(text).strip()
        if not text:
            raise ValueError(f"database: empty; give {URL_FORMS}")
        if "://" not in text:
            return cls("sqlite", path=Path(text))
        scheme = text.split("://", 1)[0].lower()
        if scheme == "sqlite":
            rest = text[len("sqlite:///") :] if text.lower().startswith("sqlite:///") else ""
            if not rest:
                raise ValueError(f"database: {text!r} names no file; use sqlite:///path")
            return cls("sqlite", path=Path(rest))
        if scheme in POSTGRES_SCHEMES:
            try:
                url = make_url(text)
            except ArgumentError as exc:
                raise ValueError(f"database: cannot read the URL ({exc}); use {URL_FORMS}") from exc
            if not url.database:
                raise ValueError("database: the PostgreSQL URL names no database (postgresql://user@host/dbname)")
            return cls("postgresql", url=url.set(drivername="postgresql+psycopg"))
        raise ValueError(f"database: {scheme!r} databases are not supported; use {URL_FORMS}")

    @property
    def display(self) -> str:
        """How messages name the database: the file path, or the URL with its password hidden."""
        if self.kind == "sqlite":
            return str(self.path)
        assert self.url is not None
        return self.url.set(drivername="postgresql").render_as_string(hide_password=True)

    @property
    def is_sqlite(self) -> bool:
        return self.kind == "sqlite"
