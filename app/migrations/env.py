"""Alembic environment: migrations run on the connection that :mod:`app.storage` hands over (one transaction).

There is no alembic.ini: :func:`app.storage.alembic_config` builds the configuration in code and puts the open
connection into ``config.attributes["connection"]``.
"""

from __future__ import annotations

from alembic import context

connection = context.config.attributes.get("connection")
if connection is None:
    raise RuntimeError("run the migrations through `assembly-agent db upgrade` (no alembic.ini here)")
context.configure(connection=connection, target_metadata=None)
with context.begin_transaction():
    context.run_migrations()
