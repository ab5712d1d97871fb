"""What a rectangle drawn on the colour image says: which part is inside it, and where that part stands.

Used when the user draws a box over a part to start tracking it (``POST /api/boxes``):

* :func:`guess_part`: the coloured part with the most pixels of its colour inside the box;
* :func:`pose_from_rect`: the part's camera-frame pose, resting on the table under the box.

Rectangles are ``(x, y, w, h)`` in colour-image pixels; depth in metres, registered to the colour image; poses in
the camera frame (metres, quaternions ``[x, y, z, w]``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tracker.geometry.camera import Intrinsics
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose


def pose_from_rect(
    part: PartSpec,
    rect: tuple[float, float, float, float],
    intrinsics: Intrinsics,
    table: Any,
    depth: np.ndarray | None,
) -> Pose:
    """Camera-frame pose of ``part`` resting on the table under the pixel rectangle ``(x, y, w, h)``.

    The rectangle centre's viewing ray is intersected with the ``table`` plane (perception's ``TablePlane`` or
    ``None``) and the part is lifted by half its height along the table normal, in the table's fundamental
    orientation (body y up). Without a table plane, the median depth inside the rectangle (plus half the part's
    size) is used. ValueError when neither is available.
    """
    x, y, w, h = (float(v) for v in rect)
    if w <= 0 or h <= 0:
        raise ValueError(f"rectangle must have a positive width and height, got w={w}, h={h}")
    u, v = x + w / 2.0, y + h / 2.0
    half = (part.box[1] if part.box is not None else part.bounding_radius()) / 2.0
    ray = np.array([(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy, 1.0])
    if table is not None:
        n = np.asarray(table.normal, float)
        denom = float(n @ ray)
        if abs(denom) > 1e-9:
            s = -float(table.offset) / denom
            if s > 0:
                t2c = table.table_to_camera()
                centre = ray * s + n * half
                return Pose(centre, t2c.q)
    if depth is None:
        raise ValueError("cannot place a part: no table plane found yet and the frame has no depth")
    x0, y0 = max(0, int(x)), max(0, int(y))
    patch = depth[y0 : int(y + h) + 1, x0 : int(x + w) + 1]
    vals = patch[np.isfinite(patch)]
    if vals.size == 0:
        raise ValueError("cannot place a part: no depth inside the rectangle")
    z = float(np.median(vals)) + half
    return Pose(ray * z, np.array([0.0, 0.0, 0.0, 1.0]))


def guess_part(
    parts: list[PartSpec], detector: Any, rgb: np.ndarray, rect: tuple[float, float, float, float]
) -> str:
    """Name of the coloured part (of ``parts``) with the most pixels of its colour inside the rectangle.

    Uses the colour ``detector``'s masks (a ``ColorDetector`` or ``None``; so the table's own colour does not
    count); falls back to the nominal colour nearest in hue to the rectangle's saturated pixels. ``rgb``: the
    colour image (H×W×3 uint8). ValueError for an empty rectangle, one outside the image, or no coloured part.
    """
    import cv2

    x, y, w, h = (int(round(v)) for v in rect)
    x0, y0 = max(0, x), max(0, y)
    coloured = [p for p in parts if p.color is not None]
    if w <= 0 or h <= 0 or not coloured:
        raise ValueError("name the part: the rectangle is empty or no part has a colour")
    if detector is not None:
        masks = detector.masks(rgb)
        counts = {name: int(np.count_nonzero(mask[y0 : y + h, x0 : x + w])) for name, mask in masks.items()}
        best = max(counts, key=counts.get) if counts else None
        if best is not None and counts[best] > 0:
            return best
    patch = rgb[y0 : y + h, x0 : x + w]
    if patch.size == 0:
        raise ValueError("name the part: the rectangle lies outside the image")
    hsv = cv2.cvtColor(patch.reshape(-1, 1, 3), cv2.COLOR_RGB2HSV).reshape(-1, 3).astype(float)
    sat = hsv[:, 1] > 60
    if sat.any():
        hsv = hsv[sat]
    ang = hsv[:, 0] * (2 * np.pi / 180.0)  # OpenCV hue is 0..180
    hue = (np.arctan2(np.sin(ang).mean(), np.cos(ang).mean()) % (2 * np.pi)) * 180.0 / (2 * np.pi)

    def hue_distance(p: PartSpec) -> float:
        d = abs(float(cv2.cvtColor(np.uint8([[p.color]]), cv2.COLOR_RGB2HSV)[0, 0, 0]) - hue)
        return min(d, 180.0 - d)

    return min(coloured, key=hue_distance).name
