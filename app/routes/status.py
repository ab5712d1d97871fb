"""``/api/status``, ``/api/snapshot`` and ``/api/frame.jpg``: what the server is doing and its latest frame."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Response

from app import api_models as m
from app.routes.deps import SettingsDep, State
from app.state import version

router = APIRouter(tags=["status"])


@router.get("/api/status", response_model=m.Status)
def status(state: State) -> m.Status:
    pipeline = state.worker.pipeline
    snap = state.worker.latest
    return m.Status(
        version=version(),
        source=state.source_spec,
        mode=state.mode,
        task=state.task,
        parts=[p.name for p in pipeline.parts] if pipeline else [],
        viser_port=state.scene.port if state.scene is not None else None,
        session_id=state.session_id,
        worker=m.WorkerStatus(**state.worker.status()),
        instruction=snap.instruction if snap else "",
        storage=m.StorageStatus(**state.storage.status()),
    )


@router.get(
    "/api/frame.jpg",
    tags=["stream"],
    response_class=Response,
    responses={200: {"content": {"image/jpeg": {}}}, 503: {"model": m.Message}},
)
def frame_jpeg(state: State, settings: SettingsDep) -> Response:
    got = state.worker.jpeg(settings.jpeg_quality)
    if got is None:
        raise HTTPException(503, "no frame yet")
    index, data = got
    return Response(data, media_type="image/jpeg", headers={"Cache-Control": "no-store", "X-Frame-Index": str(index)})


@router.get("/api/snapshot", response_model=m.SnapshotModel, tags=["stream"], responses={503: {"model": m.Message}})
def snapshot(state: State) -> dict:
    """The latest processed frame (the same JSON as one ``/ws`` message)."""
    snap = state.worker.latest
    if snap is None:
        raise HTTPException(503, "no frame processed yet")
    return snap.to_dict()
