"""``/api/boxes`` and ``/api/parts/auto-place``: placing parts by a drawn rectangle or by a search on the table."""

from __future__ import annotations

from fastapi import APIRouter

from app import api_models as m
from app.routes.deps import State, on_worker
from tracker.pipeline import AssemblyPipeline

router = APIRouter(tags=["stream"])

MAX_BOXES_KEPT = 50
"""``GET /api/boxes`` lists the newest this many boxes."""


@router.post(
    "/api/boxes", response_model=m.BoxResponse, responses={409: {"model": m.Message}, 422: {"model": m.Message}}
)
def draw_box(body: m.BoxRequest, state: State) -> m.BoxResponse:
    rect = (body.x, body.y, body.w, body.h)

    def apply(pipeline: AssemblyPipeline | None, frame):
        if pipeline is None or frame is None:
            raise LookupError("no frame processed yet")
        name = body.part or pipeline.guess_part(frame.color, rect)
        pipeline.part(name)
        if body.action == "calibrate":
            pipeline.calibrate_color(name, frame.color, rect)
            return name, None, frame.index
        pose = pipeline.pose_from_rect(name, rect, frame.depth)
        pipeline.set_part_pose(name, pose)
        state.user_poses[name] = pose
        return name, pose, frame.index

    name, pose, index = on_worker(state, apply)
    box = m.BoxResponse(
        part=name, action=body.action, rect=list(rect), pose=None if pose is None else pose.to_dict(), frame_index=index
    )
    state.boxes.append(box)
    del state.boxes[:-MAX_BOXES_KEPT]
    return box


@router.get("/api/boxes", response_model=m.BoxList)
def list_boxes(state: State) -> m.BoxList:
    return m.BoxList(boxes=state.boxes)


@router.post(
    "/api/parts/auto-place",
    response_model=m.AutoPlaceResponse,
    responses={409: {"model": m.Message}, 422: {"model": m.Message}, 503: {"model": m.Message}},
)
def auto_place(state: State, body: m.AutoPlaceRequest | None = None) -> m.AutoPlaceResponse:
    """Find the parts (default: those without a pose) resting on the table in the latest frame and track
    them from there; a part that is not found is reported in its result and stays untracked."""
    names = None if body is None else body.names

    def apply(pipeline: AssemblyPipeline | None, frame):
        if pipeline is None or frame is None:
            raise LookupError("no frame processed yet")
        results = pipeline.auto_place(frame, names)
        for name, r in results.items():
            if "error" not in r:
                state.user_poses[name] = pipeline.poses[name]
        return results, frame.index

    results, index = on_worker(state, apply)
    return m.AutoPlaceResponse(frame_index=index, results={k: m.AutoPlaceResult(**v) for k, v in results.items()})
