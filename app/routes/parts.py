"""``/api/boxes``, ``/api/calibration`` and ``/api/parts/auto-place``: placing parts by a drawn rectangle or a
search on the table, learning a part's colour from a rectangle (and undoing that)."""

from __future__ import annotations

import cv2
from fastapi import APIRouter

from app import api_models as m
from app.routes.deps import Learner, State, on_worker
from app.state import AppState, Calibration
from tracker.perception.box_checks import check_calibration, check_track_box, raised_share
from tracker.perception.box_tools import guess_part, pose_from_rect
from tracker.perception.color_detection import calibrate_range, clean_mask
from tracker.perception.hsv_range import preset_range
from tracker.pipeline import AssemblyPipeline

router = APIRouter(tags=["stream"])

MAX_BOXES_KEPT = 50
"""``GET /api/boxes`` lists the newest this many boxes."""


def inside_image(rect: tuple[float, float, float, float], width: int, height: int) -> tuple[float, float, float, float]:
    """``rect`` = (x, y, w, h) pixels cut to the ``width`` × ``height`` image; ValueError when less than half of it
    lies inside the image (a box drawn off the image, or coordinates of another image size)."""
    x, y, w, h = rect
    x1, y1 = min(x + w, float(width)), min(y + h, float(height))
    inside = max(0.0, x1 - x) * max(0.0, y1 - y)
    if inside < 0.5 * w * h or inside < 1.0:
        raise ValueError(
            f"the box [{x:.0f}, {y:.0f}, {w:.0f}, {h:.0f}] lies mostly outside the {width}×{height} image; "
            "draw it on the image"
        )
    return (x, y, x1 - x, y1 - y)


@router.post(
    "/api/boxes",
    response_model=m.BoxResponse,
    dependencies=[Learner],
    responses={409: {"model": m.Message}, 422: {"model": m.Message}, 429: {"model": m.Message}},
)
def draw_box(body: m.BoxRequest, state: State) -> m.BoxResponse:
    """Track a part from a drawn rectangle, or learn its colour from it; a box with no part in it, or a
    calibration that would cover most of the image, is refused (422) with what to do instead. A rectangle
    that overhangs the image is cut to it, one lying mostly outside is refused (422)."""
    rect = (body.x, body.y, body.w, body.h)

    def apply(pipeline: AssemblyPipeline | None, frame):
        nonlocal rect
        if pipeline is None or frame is None:
            raise LookupError("no frame processed yet")
        rect = inside_image(rect, frame.color.shape[1], frame.color.shape[0])
        if body.part is not None:
            pipeline.part(body.part)  # an unknown name: ValueError
        if body.action == "calibrate":
            name = body.part or guess_part(pipeline.parts, pipeline.detector, frame.color, rect)
            rng = calibrate_range(frame.color, rect)
            check_calibration(rng, cv2.cvtColor(frame.color, cv2.COLOR_RGB2HSV))
            state.calibrations.append(Calibration(name, rng, frame.index))
            pipeline.detector = state.detector_for(pipeline)
            return name, None, frame.index
        raised = raised_share(frame.depth, frame.intrinsics, pipeline.table, rect)
        masks = pipeline.detector.masks(frame.color) if pipeline.detector is not None else {}
        name = check_track_box(masks, rect, body.part, raised) or guess_part(
            pipeline.parts, pipeline.detector, frame.color, rect
        )
        pose = pose_from_rect(pipeline.part(name), rect, pipeline.intrinsics, pipeline.table, frame.depth)
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


def calibration_list(state: AppState) -> m.CalibrationList:
    return m.CalibrationList(
        calibrations=[m.CalibrationInfo(part=c.part, frame_index=c.frame_index) for c in state.calibrations]
    )


@router.get("/api/calibration", response_model=m.CalibrationList)
def calibrations(state: State) -> m.CalibrationList:
    """The colour calibrations in force (oldest first); each replaced its part's preset range."""
    return calibration_list(state)


@router.post(
    "/api/calibration/undo",
    response_model=m.CalibrationList,
    dependencies=[Learner],
    responses={409: {"model": m.Message}, 429: {"model": m.Message}},
)
def undo_calibration(state: State) -> m.CalibrationList:
    """Undo the newest colour calibration: its part's range goes back to the one before it."""

    def apply(pipeline: AssemblyPipeline | None, _frame):
        if not state.calibrations:
            raise LookupError("no colour calibration to undo")
        state.calibrations.pop()
        if pipeline is not None:
            pipeline.detector = state.detector_for(pipeline)

    on_worker(state, apply)
    return calibration_list(state)


@router.get("/api/boxes", response_model=m.BoxList)
def list_boxes(state: State) -> m.BoxList:
    return m.BoxList(boxes=state.boxes)


@router.post(
    "/api/parts/auto-place",
    response_model=m.AutoPlaceResponse,
    dependencies=[Learner],
    responses={
        409: {"model": m.Message},
        422: {"model": m.Message},
        429: {"model": m.Message},
        503: {"model": m.Message},
    },
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


def identical_list(state: AppState) -> m.IdenticalParts:
    return m.IdenticalParts(colour=state.identical.colour, parts=state.identical.names())


@router.get("/api/identical-parts", response_model=m.IdenticalParts)
def identical_parts(state: State) -> m.IdenticalParts:
    """Parts of one colour told apart in the image (Algorithm 2); their boxes are in every snapshot."""
    return identical_list(state)


@router.post(
    "/api/identical-parts",
    response_model=m.IdenticalParts,
    dependencies=[Learner],
    responses={409: {"model": m.Message}, 422: {"model": m.Message}, 429: {"model": m.Message}},
)
def add_identical_part(body: m.IdenticalBox, state: State) -> m.IdenticalParts:
    """One box per part of the same colour (``red #1``, ``red #2``, …, in drawing order); each keeps its name
    through contacts and short occlusions. A box with none of that colour in it is refused; another colour
    starts a new set."""
    rect = (body.x, body.y, body.w, body.h)

    def apply(pipeline: AssemblyPipeline | None, frame):
        if pipeline is None or frame is None:
            raise LookupError("no frame processed yet")
        box = inside_image(rect, frame.color.shape[1], frame.color.shape[0])
        ranges = dict(getattr(pipeline.detector, "ranges", {}) or {})
        rng = ranges.get(body.colour)
        if rng is None:
            try:
                rng = preset_range(body.colour)
            except ValueError as exc:
                raise ValueError(f"colour {body.colour!r}: name a part or a preset colour") from exc
        mask = clean_mask(rng.mask(cv2.cvtColor(frame.color, cv2.COLOR_RGB2HSV)))
        check_track_box({body.colour: mask}, box, None)
        return state.identical.add(body.colour, rng, box)

    on_worker(state, apply)
    return identical_list(state)


@router.delete(
    "/api/identical-parts",
    response_model=m.IdenticalParts,
    dependencies=[Learner],
    responses={429: {"model": m.Message}},
)
def clear_identical_parts(state: State) -> m.IdenticalParts:
    """Stop telling identical parts apart."""
    state.identical.clear()
    return identical_list(state)
