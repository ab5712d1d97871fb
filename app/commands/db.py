"""``assembly-agent db check|backup|restore``: look after the SQLite database of teacher tasks and sessions.

``backup FILE`` writes a consistent copy (SQLite's online backup: safe while the server runs); ``restore FILE``
checks the copy and puts it in place of the database (stop the server first), keeping the replaced file beside
it as ``<name>.before-restore-<time>``; ``check`` runs SQLite's integrity check and prints what the file holds.
"""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "db",
        help="check, back up or restore the database (teacher tasks, sessions, teacher password hash)",
        description="Look after the server's SQLite database (default: the serve command's --database, "
        "ASSEMBLY_AGENT_DATABASE or data/assembly-agent.sqlite3).",
    )
    p.add_argument("--database", help="SQLite file or sqlite:///path URL (default: as for serve)")
    actions = p.add_subparsers(dest="db_action", metavar="ACTION", required=True)
    actions.add_parser("check", help="run the integrity check and print the counts of tasks and sessions")
    b = actions.add_parser("backup", help="write a consistent copy of the database to FILE (server may run)")
    b.add_argument("file", metavar="FILE")
    b.add_argument("--force", action="store_true", help="overwrite FILE if it exists")
    r = actions.add_parser("restore", help="replace the database by the backup FILE (stop the server first)")
    r.add_argument("file", metavar="FILE")
    p.set_defaults(func=run)


def _summary(info: dict[str, int]) -> str:
    return f"{info['tasks']} teacher task(s), {info['sessions']} session(s), schema version {info['schema_version']}"


def run(args: argparse.Namespace) -> int:
    from app.settings import Settings
    from app.storage import StorageError, backup_database, check_database, restore_database

    settings = Settings(**({"database": args.database} if args.database else {}))
    database = settings.database_path()
    try:
        if args.db_action == "check":
            print(f"{database}: intact; {_summary(check_database(database))}")
        elif args.db_action == "backup":
            info = backup_database(database, args.file, overwrite=args.force)
            print(f"backed up {database} to {args.file}: {_summary(info)}")
        else:
            info, kept = restore_database(args.file, database)
            print(f"restored {database} from {args.file}: {_summary(info)}")
            if kept is not None:
                print(f"the replaced database is kept as {kept}")
    except StorageError as exc:
        raise ValueError(str(exc)) from exc
    return 0
