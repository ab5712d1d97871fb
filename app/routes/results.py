"""``/api/results`` and ``/api/results.csv``: learner results for the teacher (per task, per station, per step).

Both need the teacher (results are about learners). ``task`` and ``station`` filter; without them every
session with a mode is included (newest :data:`LIMIT` sessions).
"""

from __future__ import annotations

import csv
import io
from typing import Annotated

from fastapi import APIRouter, Query
from fastapi.responses import Response

from app import api_models as m
from app.results import CSV_COLUMNS, csv_rows, summarise, task_name
from app.routes.deps import StorageDep, Teacher
from app.routes.tasks import TEACHER_ONLY

router = APIRouter(tags=["results"])
LIMIT = 2000
Filter = Annotated[str | None, Query(max_length=200, pattern=r"^[^\x00-\x1f]*$")]


def _filtered(storage, task: str | None, station: str | None) -> tuple[list[dict], list[dict]]:
    """(all sessions, those matching the filters); a task filter matches the task's name as :func:`task_name`."""
    sessions = storage.results(limit=LIMIT)["sessions"]
    chosen = [s for s in sessions if (task is None or task_name(s) == task)
              and (station is None or (s.get("station") or "(unnamed)") == station)]
    return sessions, chosen


@router.get("/api/results", response_model=m.Results, dependencies=[Teacher], responses=TEACHER_ONLY)
def results(storage: StorageDep, task: Filter = None, station: Filter = None) -> dict:
    """Sessions (newest first), mean time and error rate per step, and totals per task and per station; the
    tasks and stations there are (for the filters). Times in seconds, error rates 0..1."""
    everything, chosen = _filtered(storage, task, station)
    return {
        "filters": {"task": task, "station": station},
        "tasks": sorted({task_name(s) for s in everything}),
        "stations": sorted({s.get("station") or "(unnamed)" for s in everything}),
        **summarise(chosen),
    }


@router.get(
    "/api/results.csv",
    dependencies=[Teacher],
    response_class=Response,
    responses={**TEACHER_ONLY, 200: {"content": {"text/csv": {}}, "description": "one row per step"}},
)
def results_csv(storage: StorageDep, task: Filter = None, station: Filter = None) -> Response:
    """One CSV row per step of every matching session (columns: see ``app.results.CSV_COLUMNS``)."""
    _, chosen = _filtered(storage, task, station)
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(CSV_COLUMNS)
    writer.writerows(csv_rows(chosen))
    return Response(
        buf.getvalue(),
        media_type="text/csv; charset=utf-8",
        headers={"Content-Disposition": 'attachment; filename="assembly-agent-results.csv"'},
    )
