"""``/api/tasks``: the teacher's sentence tasks (anyone reads; creating, editing and deleting need the teacher)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Path

from app import api_models as m
from app.routes.deps import StorageDep, Teacher
from app.validation import MAX_TEACHER_TASK_ID
from tracker.assembly import SentenceTask

router = APIRouter(tags=["tasks"])

TEACHER_ONLY = {401: {"model": m.Message}, 403: {"model": m.Message}}
TaskId = Annotated[int, Path(ge=1, le=MAX_TEACHER_TASK_ID, description="the task's id (teacher:<id>)")]


def no_task(task_id: int) -> HTTPException:
    """The 404 for a task id the store does not have."""
    return HTTPException(404, f"no task with id {task_id}")


def found(record: dict[str, Any] | None, task_id: int) -> dict[str, Any]:
    """``record`` itself, or a 404 naming the task id when the store had no such task."""
    if record is None:
        raise no_task(task_id)
    return record


def task_record(rec: dict[str, Any]) -> m.TaskRecord:
    return m.TaskRecord(
        id=rec["id"],
        ref=f"teacher:{rec['id']}",
        task=SentenceTask(**rec["data"]),
        created_at=rec["created_at"],
        updated_at=rec["updated_at"],
    )


@router.get("/api/tasks", response_model=m.TaskList)
def list_tasks(storage: StorageDep) -> m.TaskList:
    return m.TaskList(tasks=[task_record(r) for r in storage.list_tasks()])


@router.post("/api/tasks", response_model=m.TaskRecord, status_code=201, dependencies=[Teacher], responses=TEACHER_ONLY)
def create_task(body: SentenceTask, storage: StorageDep) -> m.TaskRecord:
    return task_record(storage.create_task(body.model_dump(mode="json")))


@router.get("/api/tasks/{task_id}", response_model=m.TaskRecord, responses={404: {"model": m.Message}})
def get_task(task_id: TaskId, storage: StorageDep) -> m.TaskRecord:
    return task_record(found(storage.get_task(task_id), task_id))


@router.put(
    "/api/tasks/{task_id}",
    response_model=m.TaskRecord,
    dependencies=[Teacher],
    responses={**TEACHER_ONLY, 404: {"model": m.Message}},
)
def update_task(task_id: TaskId, body: SentenceTask, storage: StorageDep) -> m.TaskRecord:
    return task_record(found(storage.update_task(task_id, body.model_dump(mode="json")), task_id))


@router.delete(
    "/api/tasks/{task_id}",
    response_model=m.Message,
    dependencies=[Teacher],
    responses={**TEACHER_ONLY, 404: {"model": m.Message}},
)
def delete_task(task_id: TaskId, storage: StorageDep) -> m.Message:
    if not storage.delete_task(task_id):
        raise no_task(task_id)
    return m.Message(detail=f"task {task_id} deleted")
