"""Checks on a rectangle the user drew on the colour image before it moves a part or changes a colour range.

A box that would start tracking a part over empty table, or a calibration learnt from the table's own
pixels (its range then covers most of the image, more than :data:`MAX_CALIBRATED_SHARE`), is refused with a
:class:`BoxRefused` (a ``ValueError``) whose message says what to do instead. Evidence that a part is inside a
track box:

* colour: pixels of the part's (cleaned) colour mask inside the box, at least :data:`MIN_COLOUR_SHARE` of
  the box and :data:`MIN_PIXELS`;
* depth: pixels inside the box standing more than :data:`MIN_HEIGHT_M` above the table plane, at least
  :data:`MIN_RAISED_SHARE` of the box's valid depth pixels (only with a depth image and a table plane).

Rectangles are ``(x, y, w, h)`` in colour-image pixels; depth in metres, registered to the colour image.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tracker.geometry.camera import Intrinsics
from tracker.perception.color_detection import KERNEL_SIZE, clean_mask, clip_rect
from tracker.perception.hsv_range import HSVRange

MIN_COLOUR_SHARE = 0.03
"""A track box must have at least this share of its pixels in the part's colour."""
MIN_PIXELS = 12
"""… and at least this many of them (pixels)."""
MIN_HEIGHT_M = 0.01
"""A depth pixel this far above the table (metres) belongs to something standing on it."""
MIN_RAISED_SHARE = 0.05
"""A box holds a part when at least this share of its valid depth pixels stands above the table."""
MAX_CALIBRATED_SHARE = 0.2
"""A calibrated colour range may cover at most this share of the image (more: it learnt the background)."""


class BoxRefused(ValueError):
    """The drawn box was not used; the message says why and what to do instead."""


def colour_pixels(masks: dict[str, np.ndarray], rect) -> dict[str, int]:
    """Per part, the pixels of its colour mask inside ``rect``."""
    if not masks:
        return {}
    h, w = next(iter(masks.values())).shape[:2]
    x, y, bw, bh = clip_rect(rect, w, h)
    return {name: int(np.count_nonzero(m[y : y + bh, x : x + bw])) for name, m in masks.items()}


def raised_share(depth: np.ndarray | None, intrinsics: Intrinsics, table: Any, rect) -> float | None:
    """Share of the valid depth pixels in ``rect`` standing more than :data:`MIN_HEIGHT_M` above ``table``
    (a plane with ``height(points)``); ``None`` without depth, table or valid pixels."""
    if depth is None or table is None:
        return None
    h, w = depth.shape[:2]
    x, y, bw, bh = clip_rect(rect, w, h)
    d = depth[y : y + bh, x : x + bw]
    v, u = np.mgrid[y : y + bh, x : x + bw]
    ok = np.isfinite(d) & (d > 0)
    if not ok.any():
        return None
    pts = intrinsics.backproject(u[ok].astype(float), v[ok].astype(float), d[ok])
    return float(np.mean(table.height(pts) > MIN_HEIGHT_M))


def check_track_box(
    masks: dict[str, np.ndarray], rect, part: str | None, raised: float | None = None
) -> str | None:
    """The part a track box shows: ``part`` when given and supported, else the colour with most pixels.

    Returns ``None`` when ``part`` is ``None`` and no colour is in the box but the caller may still guess
    (no masks at all). Raises :class:`BoxRefused` when the box shows no part: no colour of the named or any
    part, and (when depth is known: ``raised``) nothing standing on the table.
    """
    counts = colour_pixels(masks, rect)
    x, y, w, h = (float(v) for v in rect)
    area = max(1.0, w * h)

    def enough(n: int) -> bool:
        return n >= MIN_PIXELS and n >= MIN_COLOUR_SHARE * area

    standing = raised is not None and raised >= MIN_RAISED_SHARE
    if part is not None:
        if part in counts and not enough(counts[part]):
            if standing:
                return part  # something stands there: the user says what it is (e.g. a colour not calibrated yet)
            raise BoxRefused(
                f"no {part} part in the box ({counts[part]} pixels of its colour, nothing standing on the table): "
                "draw the box around the part, or calibrate its colour first"
            )
        return part
    if not counts:
        return None
    best = max(counts, key=lambda n: counts[n])
    if enough(counts[best]):
        return best
    what = "nothing stands on the table there" if raised is not None and not standing else "no part's colour"
    raise BoxRefused(
        f"no part in the box ({what}; at most {counts[best]} pixels of one part's colour): draw it tightly around "
        "one part, or choose the part in the list"
    )


def check_calibration(rng: HSVRange, hsv_u8: np.ndarray, kernel_size: int = KERNEL_SIZE) -> float:
    """Refuse a calibrated range that covers most of the image (learnt from the table or background, not from
    a part); returns the share of the image it covers. ``hsv_u8``: the frame in OpenCV 8-bit HSV."""
    mask = clean_mask(rng.mask(hsv_u8), kernel_size)
    share = float(np.count_nonzero(mask)) / max(1, mask.size)
    if share > MAX_CALIBRATED_SHARE:
        raise BoxRefused(
            f"calibration refused: the colour learnt from the box covers {share:.0%} of the image (the table or "
            "background, not a part); draw the box inside the part"
        )
    return share
