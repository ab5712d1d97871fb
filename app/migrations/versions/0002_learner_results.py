"""Learner results: the station of a session, its totals, and one row per assembly step.

``sessions`` gains ``station`` (the ``--station`` name), ``steps_total``, ``completed_at`` (wall-clock seconds,
``NULL`` until the task was completed), ``wrong_placements`` and ``hints``. ``session_steps`` holds each step:
its attempt (a looping source starts the task again: attempt 1, 2, …), index (1-based), label, verdict
(``done`` or ``unfinished``), start/end (wall-clock seconds), duration (seconds) and the wrong placements and
hints during it.

Revision ID: 0002
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.add_column("sessions", sa.Column("station", sa.Text))
    op.add_column("sessions", sa.Column("steps_total", sa.Integer))
    op.add_column("sessions", sa.Column("completed_at", sa.Float))
    op.add_column("sessions", sa.Column("wrong_placements", sa.Integer, nullable=False, server_default="0"))
    op.add_column("sessions", sa.Column("hints", sa.Integer, nullable=False, server_default="0"))
    op.create_table(
        "session_steps",
        sa.Column("id", sa.Integer, primary_key=True, autoincrement=True),
        sa.Column("session_id", sa.Integer, sa.ForeignKey("sessions.id", ondelete="CASCADE"), nullable=False),
        sa.Column("attempt", sa.Integer, nullable=False),
        sa.Column("step", sa.Integer, nullable=False),
        sa.Column("label", sa.Text),
        sa.Column("verdict", sa.Text, nullable=False),
        sa.Column("started_at", sa.Float, nullable=False),
        sa.Column("ended_at", sa.Float, nullable=False),
        sa.Column("duration_s", sa.Float, nullable=False),
        sa.Column("wrong_placements", sa.Integer, nullable=False, server_default="0"),
        sa.Column("hints", sa.Integer, nullable=False, server_default="0"),
        sqlite_autoincrement=True,
    )
    op.create_index("ix_session_steps_session", "session_steps", ["session_id"])
    op.create_index("ix_sessions_station", "sessions", ["station"])
    op.execute("INSERT INTO schema_version (version) VALUES (2)")


def downgrade() -> None:
    op.drop_index("ix_sessions_station", "sessions")
    op.drop_table("session_steps")
    for column in ("hints", "wrong_placements", "completed_at", "steps_total", "station"):
        op.drop_column("sessions", column)
    op.execute("DELETE FROM schema_version WHERE version = 2")
