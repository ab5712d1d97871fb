"""``assembly-agent db upgrade|check|backup|restore``: look after the database of teacher tasks, sessions and results.

``upgrade`` applies the missing schema migrations (Alembic; the server also does this at start) to a SQLite file or
a PostgreSQL database and says from which revision to which; it refuses a database of a newer program.
``backup FILE`` writes a consistent copy of a SQLite file (SQLite's online backup: safe while the server runs);
``restore FILE`` checks the copy and puts it in place of the database (stop the server first), keeping the
replaced file beside it as ``<name>.before-restore-<time>``; ``check`` runs SQLite's integrity check and prints
what the file holds (on PostgreSQL: connects and prints the counts). PostgreSQL databases are backed up with the
PostgreSQL tools (``pg_dump`` / ``pg_restore``).
"""

from __future__ import annotations

import argparse
from typing import Any


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "db",
        help="upgrade, check, back up or restore the database (teacher tasks, sessions, results, password hash)",
        description="Look after the server's database (default: the serve command's --database, "
        "ASSEMBLY_AGENT_DATABASE or data/assembly-agent.sqlite3).",
    )
    p.add_argument(
        "--database", help="SQLite file, sqlite:///path or postgresql://user@host/dbname (default: as for serve)"
    )
    actions = p.add_subparsers(dest="db_action", metavar="ACTION", required=True)
    actions.add_parser("upgrade", help="apply the missing schema migrations (the server does this at start too)")
    actions.add_parser("check", help="run the integrity check and print the counts of tasks and sessions")
    b = actions.add_parser("backup", help="write a consistent copy of a SQLite database to FILE (server may run)")
    b.add_argument("file", metavar="FILE")
    b.add_argument("--force", action="store_true", help="overwrite FILE if it exists")
    r = actions.add_parser("restore", help="replace a SQLite database by the backup FILE (stop the server first)")
    r.add_argument("file", metavar="FILE")
    p.set_defaults(func=run)


def _summary(info: dict[str, Any]) -> str:
    revision = info.get("revision") or f"old scheme version {info.get('legacy_version')} (upgraded when opened)"
    return f"{info['tasks']} teacher task(s), {info['sessions']} session(s), schema revision {revision}"


def run(args: argparse.Namespace) -> int:
    from app.settings import Settings
    from app.storage import Storage, StorageError, backup_database, check_database, restore_database

    settings = Settings(**({"database": args.database} if args.database else {}))
    target = settings.database_target()
    try:
        if args.db_action == "upgrade":
            storage = Storage(target)  # opening migrates (and refuses a newer or damaged database)
            assert storage.migration is not None
            before, after = storage.migration
            storage.dispose()
            was = f" (was {before or 'empty'})" if before != after else ""
            print(f"{target.display}: schema at revision {after}{was}")
        elif args.db_action == "check" and target.path is None:
            storage = Storage(target)
            info = {**storage.counts(), "revision": storage.schema_version()}
            storage.dispose()
            print(f"{target.display}: reachable; {_summary(info)}")
        elif args.db_action == "check":
            print(f"{target.path}: intact; {_summary(check_database(target.path))}")
        elif args.db_action == "backup":
            database = settings.database_path()
            info = backup_database(database, args.file, overwrite=args.force)
            print(f"backed up {database} to {args.file}: {_summary(info)}")
        else:
            database = settings.database_path()
            info, kept = restore_database(args.file, database)
            print(f"restored {database} from {args.file}: {_summary(info)}")
            if kept is not None:
                print(f"the replaced database is kept as {kept}")
    except StorageError as exc:
        raise ValueError(str(exc)) from exc
    return 0
