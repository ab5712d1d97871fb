"""Colour detection of parts with distinct colours (the seed's Algorithm 1, spec section 2.3) and range
calibration from a user-drawn rectangle (eqs 3.4–3.6, spec section 2.2).

Per part: mask of its HSV range (``cv2.inRange`` on the OpenCV 8-bit HSV image, two intervals when the hue
wraps), opening then closing with a 4×4 square kernel, **external** contours (``cv2.RETR_EXTERNAL``: holes
inside a blob do not count as separate regions), the largest contour by enclosed area, its centroid from image
moments (``m10/m00, m01/m00``; pixel coordinates, column u and row v, pixel centres at integers), and the
reliability score ``s = largest area / total area of all contours`` (eq. 3.7). With no contour (or only
degenerate zero-area contours) the part is "not detected": ``center=None``, ``score=0``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import cv2
import numpy as np

from tracker.geometry.parts import PRESET_COLORS, PartSpec
from tracker.perception.hsv_range import KAPPA, HSVRange, preset_range, rgb_to_hsv_float
from tracker.perception.range_bits import mask_crop, range_luts, rgb_bits_lut, rgb_range_bits

KERNEL_SIZE = 4
"""Side of the square structuring elements B1 (opening) and B2 (closing), pixels (thesis)."""


@dataclass
class ColorDetection:
    """2D detection of one part in one image.

    * ``center``: (u, v) pixel centroid of the largest blob, or ``None`` when not detected.
    * ``score``: reliability in [0, 1] (eq. 3.7; 0 when not detected).
    * ``area``: enclosed area of the largest contour, px².
    * ``bbox``: (x, y, w, h) of the largest contour (or the tracked box in same-colour tracking), or ``None``.
    * ``contour``: (K, 2) int32 pixel polygon of the largest contour, or ``None``.
    """

    name: str
    center: tuple[float, float] | None = None
    score: float = 0.0
    area: float = 0.0
    bbox: tuple[int, int, int, int] | None = None
    contour: np.ndarray | None = field(default=None, repr=False)

    @property
    def detected(self) -> bool:
        return self.center is not None and self.score > 0.0

    def to_dict(self, with_contour: bool = False) -> dict:
        d = {
            "name": self.name,
            "center": None if self.center is None else [float(self.center[0]), float(self.center[1])],
            "score": float(self.score),
            "area": float(self.area),
            "bbox": None if self.bbox is None else [int(x) for x in self.bbox],
        }
        if with_contour:
            d["contour"] = None if self.contour is None else self.contour.reshape(-1, 2).astype(int).tolist()
        return d


def _check_rgb(rgb: np.ndarray, who: str) -> None:
    if not isinstance(rgb, np.ndarray) or rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(
            f"{who}: expected an RGB uint8 HxWx3 image, got "
            f"{getattr(rgb, 'shape', None)} {getattr(rgb, 'dtype', type(rgb).__name__)}"
        )


def clean_mask(mask: np.ndarray, kernel_size: int = KERNEL_SIZE) -> np.ndarray:
    """Opening (removes blobs thinner than the kernel) then closing (fills small holes), square kernel."""
    if kernel_size <= 1:
        return mask
    k = np.ones((kernel_size, kernel_size), np.uint8)
    # an even-sized kernel has no centre pixel: the second operation of each pair uses the mirrored anchor so
    # that opening and closing do not shift the mask (cv2.morphologyEx would shift it by one pixel per call)
    a1 = (kernel_size // 2, kernel_size // 2)
    a2 = ((kernel_size - 1) // 2, (kernel_size - 1) // 2)
    m = cv2.dilate(cv2.erode(mask, k, anchor=a1), k, anchor=a2)
    return cv2.erode(cv2.dilate(m, k, anchor=a1), k, anchor=a2)


def clean_mask_roi(mask: np.ndarray, kernel_size: int = KERNEL_SIZE) -> tuple[np.ndarray, tuple[int, int]]:
    """:func:`clean_mask` restricted to the bounding box of the mask's pixels (padded by two kernels, so the
    result equals the full-image one). Returns the cleaned crop and its top-left offset (x, y)."""
    x, y, w, h = cv2.boundingRect(mask)
    if w == 0 or h == 0:
        return mask[0:0, 0:0], (0, 0)
    pad = 2 * kernel_size
    H, W = mask.shape
    x0, y0, x1, y1 = max(0, x - pad), max(0, y - pad), min(W, x + w + pad), min(H, y + h + pad)
    return clean_mask(np.ascontiguousarray(mask[y0:y1, x0:x1]), kernel_size), (x0, y0)


def detect_in_mask(name: str, mask: np.ndarray, offset: tuple[int, int] = (0, 0)) -> ColorDetection:
    """Largest external contour, its moment centroid and the eq. 3.7 score of a cleaned binary mask
    (``offset``: image position of the mask's top-left pixel when the mask is a crop)."""
    if mask.size == 0:
        return ColorDetection(name)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE, offset=offset)
    if not contours:
        return ColorDetection(name)
    areas = np.array([cv2.contourArea(c) for c in contours], np.float64)
    total = float(areas.sum())
    if total <= 0.0:
        return ColorDetection(name)
    m = int(np.argmax(areas))
    c = contours[m]
    mom = cv2.moments(c)
    if mom["m00"] > 0:
        center = (mom["m10"] / mom["m00"], mom["m01"] / mom["m00"])
    else:  # degenerate (cannot happen with total > 0 for the largest one, kept for safety)
        p = c.reshape(-1, 2).astype(np.float64)
        center = (float(p[:, 0].mean()), float(p[:, 1].mean()))
    x, y, w, h = cv2.boundingRect(c)
    return ColorDetection(
        name=name,
        center=(float(center[0]), float(center[1])),
        score=float(areas[m] / total),
        area=float(areas[m]),
        bbox=(int(x), int(y), int(w), int(h)),
        contour=c.reshape(-1, 2).astype(np.int32),
    )


class ColorDetector:
    """Algorithm 1: one HSV range per part, detections per image.

    ``ranges`` maps part name → :class:`HSVRange`. ``kernel_size`` is the side of B1 and B2 (4 px, thesis).
    """

    def __init__(self, ranges: Mapping[str, HSVRange], kernel_size: int = KERNEL_SIZE) -> None:
        if not ranges:
            raise ValueError("ColorDetector needs at least one HSV range")
        for name, r in ranges.items():
            if not isinstance(r, HSVRange):
                raise ValueError(f"ColorDetector: range of {name!r} must be an HSVRange, got {type(r).__name__}")
        self.ranges: dict[str, HSVRange] = dict(ranges)
        self.kernel_size = int(kernel_size)
        # (ranges they were built for, range_luts, rgb_bits_lut or None)
        self._luts: tuple[tuple, np.ndarray | None, np.ndarray | None] | None = None

    @staticmethod
    def from_parts(parts: Iterable[PartSpec | str], h_halfwidth_deg: float | None = None) -> ColorDetector:
        """Preset ranges from each part's nominal RGB (``PartSpec.color``) or colour name.

        A part with ``color=None`` whose name is a preset colour name uses that preset; other colourless parts
        are skipped (depth only). The hue half-width is, unless given, half the hue distance to the nearest other
        part's colour, clipped to [7°, 24°] — tight enough that red/orange/yellow/pink do not overlap, wide
        enough for shading and real-camera white balance.
        """
        named: dict[str, tuple[int, int, int]] = {}
        for p in parts:
            if isinstance(p, str):
                if p not in PRESET_COLORS:
                    raise ValueError(f"ColorDetector.from_parts: unknown colour name {p!r}")
                named[p] = PRESET_COLORS[p]
            elif p.color is not None:
                named[p.name] = tuple(int(c) for c in p.color)
            elif p.name in PRESET_COLORS:
                named[p.name] = PRESET_COLORS[p.name]
        if not named:
            raise ValueError("ColorDetector.from_parts: no part has a colour (give PartSpec.color or colour names)")
        hues = {n: float(rgb_to_hsv_float(np.array(c, np.float64).reshape(1, 3))[0, 0]) for n, c in named.items()}
        ranges = {}
        for n, rgb in named.items():
            if h_halfwidth_deg is not None:
                half = float(h_halfwidth_deg)
            else:
                others = [abs((hues[n] - h + 180.0) % 360.0 - 180.0) for m, h in hues.items() if m != n]
                others = [d for d in others if d > 1.0]  # same-colour parts share a range
                half = float(np.clip(min(others) / 2.0, 7.0, 24.0)) if others else 24.0
            ranges[n] = preset_range(rgb, h_halfwidth_deg=half)
        return ColorDetector(ranges)

    def masks(self, rgb: np.ndarray) -> dict[str, np.ndarray]:
        """Cleaned full-image masks M2 per part (uint8, 255 inside)."""
        _check_rgb(rgb, "ColorDetector")
        hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
        return {n: clean_mask(r.mask(hsv), self.kernel_size) for n, r in self.ranges.items()}

    def detect(self, rgb: np.ndarray) -> dict[str, ColorDetection]:
        """Detections of all parts in an RGB uint8 image (the morphology runs only around each range's
        pixels, with the same result as on the full image). All ranges' masks come from one pass over the image
        (:mod:`tracker.perception.range_bits`), equal to ``HSVRange.mask``'s."""
        _check_rgb(rgb, "ColorDetector")
        key = tuple(self.ranges.items())
        if self._luts is None or self._luts[0] != key:  # the ranges may be replaced (calibration)
            luts = range_luts(list(self.ranges.values()))
            self._luts = (key, luts, None if luts is None else rgb_bits_lut(luts))
        table = self._luts[2]
        out = {}
        if table is None:  # more than 8 ranges: one full-image mask per range
            hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
            for n, r in self.ranges.items():
                crop, off = clean_mask_roi(r.mask(hsv), self.kernel_size)
                out[n] = detect_in_mask(n, crop, off)
            return out
        bits, boxes = rgb_range_bits(rgb, table, len(key))  # = range_bits of the HSV image
        for i, n in enumerate(self.ranges):
            crop, off = mask_crop(bits, i, boxes[i], 2 * self.kernel_size)  # = clean_mask_roi's window
            out[n] = detect_in_mask(n, clean_mask(crop, self.kernel_size) if crop.size else crop, off)
        return out


def clip_rect(rect, width: int, height: int) -> tuple[int, int, int, int]:
    """Clip (x, y, w, h) to a W×H image; ValueError when nothing of it is inside or it is empty."""
    try:
        x, y, w, h = (int(round(float(v))) for v in rect)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"rectangle must be four numbers (x, y, w, h), got {rect!r}") from exc
    if w <= 0 or h <= 0:
        raise ValueError(f"rectangle {rect!r} is empty (width and height must be positive)")
    x0, y0, x1, y1 = max(x, 0), max(y, 0), min(x + w, width), min(y + h, height)
    if x1 <= x0 or y1 <= y0:
        raise ValueError(f"rectangle {rect!r} lies outside the {width}x{height} image")
    return x0, y0, x1 - x0, y1 - y0


def calibrate_range(rgb: np.ndarray, rect, kappa: float = KAPPA) -> HSVRange:
    """HSV range of the pixels in a user-drawn rectangle (x, y, w, h): mean ± κσ per channel (eqs 3.4–3.6).

    Hue mean and spread are circular (see :mod:`tracker.perception.hsv_range`); the hue interval wraps across 0° when
    needed. A rectangle partly outside the image is clipped; one fully outside or empty raises ValueError.
    """
    _check_rgb(rgb, "calibrate_range")
    x, y, w, h = clip_rect(rect, rgb.shape[1], rgb.shape[0])
    hsv = rgb_to_hsv_float(rgb[y : y + h, x : x + w].reshape(-1, 3))
    return HSVRange.from_samples(hsv[:, 0], hsv[:, 1], hsv[:, 2], kappa=kappa)
