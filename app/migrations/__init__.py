"""Alembic migrations of the database schema (SQLite and PostgreSQL alike).

Applied by :meth:`app.storage.Storage.migrate`."""
