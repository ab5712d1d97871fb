"""Writing a benchmark's figures: ``benchmarks/results/<stem>.json`` and ``<stem>.md`` (a BENCHMARKS.md section),
and the commit they were measured at."""

from __future__ import annotations

import json
import subprocess
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def git_commit() -> str:
    """Short hash of HEAD, "(+ uncommitted changes)" when tracked files differ from it; "unknown" outside git."""
    try:
        out = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, check=True).stdout.strip()
        return out + (" (+ uncommitted changes)" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def write_results(stem: str, res: dict, md: str) -> None:
    """Write ``res`` as ``<stem>.json`` and ``md`` as ``<stem>.md`` in benchmarks/results."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{stem}.json").write_text(json.dumps(res, indent=2) + "\n")
    (RESULTS / f"{stem}.md").write_text(md)
    print(f"wrote {RESULTS / stem}.json and .md")


def rewrite_markdown(stem: str, markdown: Callable[[dict], str]) -> str:
    """Rebuild ``<stem>.md`` from ``<stem>.json`` with ``markdown`` (after a change of the layout); returns it."""
    md = markdown(json.loads((RESULTS / f"{stem}.json").read_text()))
    (RESULTS / f"{stem}.md").write_text(md)
    return md
