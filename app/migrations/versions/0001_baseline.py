"""Baseline: teacher tasks, secrets and sessions, as the old ``schema_version`` scheme (version 1) made them.

A SQLite file of that scheme already has these tables: :meth:`app.storage.Storage.migrate` stamps it with this
revision instead of running it (it is adopted), so only the later revisions run on it.

Revision ID: 0001
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "tasks",
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("data", sa.Text, nullable=False),
        sa.Column("created_at", sa.Float, nullable=False),
        sa.Column("updated_at", sa.Float, nullable=False),
        sqlite_autoincrement=True,
    )
    op.create_table(
        "secrets",
        sa.Column("key", sa.Text, primary_key=True),
        sa.Column("value", sa.Text, nullable=False),
    )
    op.create_table(
        "sessions",
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("started_at", sa.Float, nullable=False),
        sa.Column("ended_at", sa.Float),
        sa.Column("source", sa.Text, nullable=False),
        sa.Column("mode", sa.Text),
        sa.Column("task", sa.Text),
        sa.Column("frames", sa.Integer, nullable=False, server_default="0"),
        sqlite_autoincrement=True,
    )
    # kept so that an older assembly-agent (which reads only this table) refuses a newer database clearly
    if not sa.inspect(op.get_bind()).has_table("schema_version"):
        op.create_table("schema_version", sa.Column("version", sa.Integer, nullable=False))
    op.execute("INSERT INTO schema_version (version) VALUES (1)")


def downgrade() -> None:
    for table in ("sessions", "secrets", "tasks", "schema_version"):
        op.drop_table(table)
