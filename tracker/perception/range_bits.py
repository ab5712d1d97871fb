"""All parts' HSV range masks in one pass over the image (a speed-up of :meth:`ColorDetector.detect`).

:meth:`HSVRange.mask <tracker.perception.hsv_range.HSVRange.mask>` runs ``cv2.inRange`` over the whole 8-bit HSV
image once per range (twice for a wrapping hue), then the detector finds each mask's bounding rectangle. Here one
pass computes, per pixel, a byte whose bit ``i`` is set when the pixel lies in range ``i`` (three 256-entry lookup
tables, one per channel, ANDed), together with each range's bounding rectangle; a range's mask is then rebuilt only
inside its (padded) rectangle. The bits are exactly ``cv2.inRange``'s: a pixel is in an OpenCV interval
``[lower, upper]`` (inclusive, per channel) when each channel's value is, and a wrapping hue's two intervals share
their S and V bounds (:meth:`HSVRange.opencv_bounds`), so their union is one hue table entry set with common S
and V entries. Up to 8 ranges (one byte); more, or bounds whose intervals differ in S or V, return None and the
caller uses the per-range masks.

:func:`rgb_bits_lut` and :func:`rgb_range_bits` take the RGB image straight to the bit image: a table of all
2^24 RGB values' bytes (16 MB, built once per set of ranges, about 0.1 s, by converting every RGB value with the
same ``cv2.cvtColor(·, COLOR_RGB2HSV)`` and the lookup tables above), so a frame needs one table read per pixel
instead of the colour conversion and three reads (same bits, same rectangles).

Units: 8-bit OpenCV HSV (H 0–179, S and V 0–255), pixel columns x and rows y.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence

import numba as nb
import numpy as np

from tracker.perception.hsv_range import HSVRange

MAX_RANGES = 8
"""Ranges one bit image holds (uint8)."""


def range_luts(ranges: Sequence[HSVRange]) -> np.ndarray | None:
    """(3, 256) uint8 lookup tables (H, S, V): bit ``i`` of entry ``[c, value]`` is set when ``value`` lies in range
    ``i``'s interval of channel ``c``; None when the ranges do not fit (see the module docstring)."""
    if not 0 < len(ranges) <= MAX_RANGES:
        return None
    luts = np.zeros((3, 256), np.uint8)
    for i, r in enumerate(ranges):
        bounds = r.opencv_bounds()
        sv = {(tuple(int(v) for v in lo[1:]), tuple(int(v) for v in hi[1:])) for lo, hi in bounds}
        if len(sv) != 1:
            return None
        bit = np.uint8(1 << i)
        for lo, hi in bounds:
            luts[0, int(lo[0]) : int(hi[0]) + 1] |= bit
        (s_lo, v_lo), (s_hi, v_hi) = next(iter(sv))
        luts[1, s_lo : s_hi + 1] |= bit
        luts[2, v_lo : v_hi + 1] |= bit
    return luts


def hsv_bits(hsv_u8: np.ndarray, luts: np.ndarray) -> np.ndarray:
    """The uint8 bit image (bit ``i``: in range ``i``) of an OpenCV 8-bit HSV image (any shape ×3) through the lookup
    tables of :func:`range_luts`."""
    return luts[0][hsv_u8[..., 0]] & luts[1][hsv_u8[..., 1]] & luts[2][hsv_u8[..., 2]]


_RGB_LUTS: dict[bytes, np.ndarray] = {}
"""The tables of :func:`rgb_bits_lut` by their lookup tables' bytes (the last few sets of ranges)."""
_RGB_LUTS_KEEP = 2
"""Tables kept (16 MB each)."""
_RGB_LUTS_LOCK = threading.Lock()
"""Held while a table is looked up or built: the server's frame reader and its pipeline thread may both detect
(:meth:`tracker.pipeline.AssemblyPipeline.prepare`); the second waits for the first's table instead of building it
again."""


def rgb_bits_lut(luts: np.ndarray) -> np.ndarray:
    """The (2^24,) uint8 table of every RGB value's bits (index ``r << 16 | g << 8 | b``) for the lookup tables
    ``luts`` of :func:`range_luts`: each value converted by ``cv2.cvtColor(·, COLOR_RGB2HSV)`` (one image row per
    red value) and looked up as :func:`range_bits` does. Kept for the last few sets of ranges."""
    key = np.ascontiguousarray(luts, np.uint8).tobytes()
    with _RGB_LUTS_LOCK:
        table = _RGB_LUTS.get(key)
        if table is None:
            table = _RGB_LUTS[key] = _build_rgb_bits_lut(luts)
    return table


def _build_rgb_bits_lut(luts: np.ndarray) -> np.ndarray:
    """The table of :func:`rgb_bits_lut` (built; made room for in the cache, which the caller fills)."""
    import cv2

    gb = np.arange(65536)
    row = np.empty((1, 65536, 3), np.uint8)
    row[0, :, 1] = (gb >> 8).astype(np.uint8)
    row[0, :, 2] = (gb & 255).astype(np.uint8)
    table = np.empty(1 << 24, np.uint8)
    lut = np.ascontiguousarray(luts, np.uint8)
    for r in range(256):
        row[0, :, 0] = r
        table[r << 16 : (r + 1) << 16] = hsv_bits(cv2.cvtColor(row, cv2.COLOR_RGB2HSV)[0], lut)
    while len(_RGB_LUTS) >= _RGB_LUTS_KEEP:
        _RGB_LUTS.pop(next(iter(_RGB_LUTS)))
    return table


@nb.njit(cache=True, nogil=True)
def _rgb_bits_kernel(rgb, table, n, bits, boxes):  # pragma: no cover - numba
    H, W = bits.shape
    rows = np.zeros(H, np.uint8)  # OR of each row's bits
    cols = np.zeros(W, np.uint8)  # OR of each column's bits
    for y in range(H):
        acc = np.uint8(0)
        for x in range(W):
            b = table[(np.int64(rgb[y, x, 0]) << 16) | (np.int64(rgb[y, x, 1]) << 8) | np.int64(rgb[y, x, 2])]
            bits[y, x] = b
            cols[x] |= b
            acc |= b
        rows[y] = acc
    _boxes_of(rows, cols, n, boxes)


@nb.njit(cache=True, nogil=True)
def _boxes_of(rows, cols, n, boxes):  # pragma: no cover - numba
    H, W = rows.shape[0], cols.shape[0]
    for i in range(n):
        boxes[i, 0] = W
        boxes[i, 1] = H
        boxes[i, 2] = -1
        boxes[i, 3] = -1
        for x in range(W):
            if (cols[x] >> i) & 1:
                if boxes[i, 0] == W:
                    boxes[i, 0] = x
                boxes[i, 2] = x
        for y in range(H):
            if (rows[y] >> i) & 1:
                if boxes[i, 1] == H:
                    boxes[i, 1] = y
                boxes[i, 3] = y


def rgb_range_bits(rgb_u8: np.ndarray, table: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`range_bits` of ``cv2.cvtColor(rgb_u8, COLOR_RGB2HSV)`` from the RGB uint8 H×W×3 image itself, through
    the table of :func:`rgb_bits_lut` (the same bit image and rectangles)."""
    H, W = rgb_u8.shape[:2]
    bits = np.empty((H, W), np.uint8)
    boxes = np.empty((n, 4), np.int64)
    _rgb_bits_kernel(np.ascontiguousarray(rgb_u8), table, n, bits, boxes)
    return bits, boxes


def range_bits(hsv_u8: np.ndarray, luts: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The H×W uint8 bit image of an OpenCV 8-bit HSV image (bit ``i``: in range ``i``) and the ranges' bounding
    rectangles as an (n, 4) int64 array of inclusive (x0, y0, x1, y1), x1 = -1 for a range with no pixel (the
    reference of :func:`rgb_range_bits`, which the detector runs)."""
    bits = np.ascontiguousarray(hsv_bits(hsv_u8, luts))
    boxes = np.empty((n, 4), np.int64)
    _boxes_of(np.bitwise_or.reduce(bits, axis=1), np.bitwise_or.reduce(bits, axis=0), n, boxes)
    return bits, boxes


def mask_crop(bits: np.ndarray, i: int, box: np.ndarray, pad: int) -> tuple[np.ndarray, tuple[int, int]]:
    """Range ``i``'s uint8 mask (255 inside) in its bounding rectangle ``box`` (from :func:`range_bits`) padded by
    ``pad`` pixels and clipped to the image, and the crop's top-left (x, y); an empty (0×0) crop at (0, 0) when the
    range has no pixel."""
    x0, y0, x1, y1 = (int(v) for v in box)
    if x1 < 0:
        return bits[0:0, 0:0], (0, 0)
    H, W = bits.shape
    x0, y0, x1, y1 = max(0, x0 - pad), max(0, y0 - pad), min(W, x1 + 1 + pad), min(H, y1 + 1 + pad)
    crop = (bits[y0:y1, x0:x1] >> np.uint8(i)) & np.uint8(1)
    return np.ascontiguousarray(crop * np.uint8(255)), (x0, y0)
