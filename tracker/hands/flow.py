"""Dense optical flow on a region of interest (hand-tracking spec §3.2, §14.2).

The thesis's Brox 2004 flow (tens of seconds per pair) is replaced by OpenCV's DIS (default) or Farnebäck flow on
greyscale crops. Flows are arrays [h, w, 2] of (u, v) in pixels per frame, x right, y down, on the crop's grid.

* :func:`forward_backward`: f^{f,1} (I_{k−1} → I_k) and f^{b,1} (I_k → I_{k−1}); if the crop's longer side exceeds
  ``max_side`` (L_ROI = 192 px) both images are downscaled by the smallest integer factor that satisfies it, and
  the flow is scaled back (values and grid).
* :func:`four_flows`: both flows and their second versions, the inversion on the reduced grid.
* :func:`invert`: the second version f^{·,2} of a flow from the other direction (eqs. 6.2–6.3), fast mode of
  §14.2: every scattered point x + f(x) receives −f(x) at its nearest grid pixel, collisions are averaged,
  empty pixels are filled from their filled neighbours (see :func:`invert`).
"""

from __future__ import annotations

import threading

import cv2
import numba as nb
import numpy as np

METHODS = ("dis", "farneback")
MIN_SIDE = 32
"""Crops with a side shorter than this are padded (edge replication) before the flow and the flow cropped back."""

_LOCAL = threading.local()
"""One DIS instance per thread and preset: an instance keeps working buffers between calls, so two threads (a hand
step in the hand loop's worker beside another in the caller's thread, or two stations' pipelines) must not share
one (they did, and the flow came out as garbage). Those buffers also make an instance's flow depend slightly on
the frames it computed before: a hand tracker therefore passes its own ``cache`` (:class:`HandTracker` keeps one),
so that its results do not depend on other trackers run before it in the same thread (session 12: in one process,
the Kalman reference run after particle-filter runs on a tuning sequence of hands-s2 scored F̄^b 0.700 instead of
its 0.751 alone)."""


def _dis(preset: int, cache: dict | None = None) -> cv2.DISOpticalFlow:
    """The DIS instance of ``preset`` in ``cache`` (None: this thread's), created on first use."""
    if cache is None:
        cache = getattr(_LOCAL, "dis", None)
        if cache is None:
            cache = _LOCAL.dis = {}
    if preset not in cache:
        cache[preset] = cv2.DISOpticalFlow_create(preset)
    return cache[preset]


def flow(prev: np.ndarray, cur: np.ndarray, method: str = "dis", cache: dict | None = None) -> np.ndarray:
    """Dense flow prev → cur of two uint8 greyscale images of one size; [h, w, 2] float32. ``cache``: where the DIS
    instances live (a dict owned by the caller, e.g. one hand tracker; None: one per thread)."""
    if method == "dis":
        return _dis(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM, cache).calc(prev, cur, None)
    if method == "dis-fast":
        return _dis(cv2.DISOPTICAL_FLOW_PRESET_FAST, cache).calc(prev, cur, None)
    if method == "farneback":
        return cv2.calcOpticalFlowFarneback(prev, cur, None, 0.5, 3, 15, 3, 5, 1.2, 0)
    raise ValueError(f"unknown optical flow method {method!r}; choose dis, dis-fast or farneback")


def forward_backward(prev: np.ndarray, cur: np.ndarray, method: str = "dis",
                     max_side: int = 192) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(forward, backward) flows of two greyscale crops, computed at a reduced size if the crop is larger than
    ``max_side``, returned on the crops' full grid in full-resolution pixels."""
    fw, bw, _, _ = four_flows(prev, cur, method, max_side, inverted=False)
    return fw, bw


def four_flows(prev: np.ndarray, cur: np.ndarray, method: str = "dis", max_side: int = 192,
               inverted: bool = True, cache: dict | None = None) -> tuple[np.ndarray, ...]:  # fmt: skip
    """(f^{f,1}, f^{b,1}, f^{f,2}, f^{b,2}) of two greyscale crops: the forward and backward flows as
    :func:`forward_backward`, and the second versions (:func:`invert` of the backward and of the forward flow). The
    inversion runs on the reduced grid the flows were computed on (a crop larger than ``max_side``), and all four
    are then scaled back, so its cost falls with the square of the reduction like the flow's. ``inverted=False``:
    the last two are None. ``cache``: see :func:`flow`."""
    h, w = prev.shape
    f = max(1, int(np.ceil(max(h, w) / float(max_side))))
    if f > 1:
        size = (max(8, w // f), max(8, h // f))
        p = cv2.resize(prev, size, interpolation=cv2.INTER_AREA)
        c = cv2.resize(cur, size, interpolation=cv2.INTER_AREA)
    else:
        p, c = prev, cur
    if min(p.shape) < 8:  # DIS needs a few pixels; a tiny crop has no usable motion
        z = np.zeros((h, w, 2), np.float32)
        return (z, z.copy(), z.copy(), z.copy()) if inverted else (z, z.copy(), None, None)
    ph, pw = p.shape
    if min(ph, pw) < MIN_SIDE:  # OpenCV's DIS crashes on thin images (seen at 13×79): pad by edge replication
        pad = ((0, max(0, MIN_SIDE - ph)), (0, max(0, MIN_SIDE - pw)))
        p, c = np.pad(p, pad, mode="edge"), np.pad(c, pad, mode="edge")
    fw = np.ascontiguousarray(flow(p, c, method, cache)[:ph, :pw])
    bw = np.ascontiguousarray(flow(c, p, method, cache)[:ph, :pw])
    flows = [fw, bw, invert(bw), invert(fw)] if inverted else [fw, bw]
    if f > 1:
        sx, sy = np.float32(w / float(pw)), np.float32(h / float(ph))
        flows = [_scaled(cv2.resize(x, (w, h), interpolation=cv2.INTER_LINEAR), sx, sy) for x in flows]
    return tuple(flows) if inverted else (flows[0], flows[1], None, None)


@nb.njit(cache=True, nogil=True)
def _scaled(f, sx, sy):
    """``f`` [h, w, 2] float32 with its u components times ``sx`` and its v components times ``sy`` (float32), in
    place (numpy's ``f * np.float32([sx, sy])`` without the slow broadcast over a last axis of 2); returns ``f``."""
    for y in range(f.shape[0]):
        for x in range(f.shape[1]):
            f[y, x, 0] *= sx
            f[y, x, 1] *= sy
    return f


def invert(f: np.ndarray) -> np.ndarray:
    """The flow of the opposite direction obtained from ``f`` [h, w, 2] by splatting (fast mode of §14.2): every
    point x + f(x) writes −f(x) to its nearest grid pixel, collisions averaged. Empty pixels are filled by
    normalised convolution (a 7×7 box average of the filled neighbours, repeated until none is empty, at most
    4 times; what remains takes the mean) — a cheaper stand-in for the spec's nearest-filled-pixel fill."""
    h, w = f.shape[:2]
    out = np.zeros((h, w, 2), np.float32)
    filled = _splat(np.ascontiguousarray(f, np.float32), out)
    if not filled.any():
        return out
    empty = ~filled
    wgt = filled.astype(np.float32)
    left = int(np.count_nonzero(empty))
    for _ in range(4):
        if not left:
            break
        num = cv2.blur(_weighted(out, wgt), (7, 7))
        den = cv2.blur(wgt, (7, 7))
        left = _fill(out, wgt, empty, num, den, np.float32(1e-6))
    if left:
        out[empty] = out[~empty].mean(axis=0)
    return out


@nb.njit(cache=True, nogil=True)
def _splat(f, out):
    """Every grid point x + f(x), rounded half to even, receives −f(x); ``out`` [h, w, 2] gets the mean of what each
    pixel received; returns the bool mask of the pixels that received something."""
    h, w = f.shape[0], f.shape[1]
    cnt = np.zeros((h, w), np.int64)
    su = np.zeros((h, w))
    sv = np.zeros((h, w))
    for y in range(h):
        for x in range(w):
            tx = int(np.rint(np.float32(x) + f[y, x, 0]))
            ty = int(np.rint(np.float32(y) + f[y, x, 1]))
            if 0 <= tx < w and 0 <= ty < h:
                cnt[ty, tx] += 1
                su[ty, tx] -= f[y, x, 0]
                sv[ty, tx] -= f[y, x, 1]
    filled = cnt > 0
    for y in range(h):
        for x in range(w):
            if filled[y, x]:
                out[y, x, 0] = np.float32(su[y, x] / cnt[y, x])
                out[y, x, 1] = np.float32(sv[y, x] / cnt[y, x])
    return filled


@nb.njit(cache=True, nogil=True)
def _weighted(out, wgt):
    """``out * wgt[..., None]`` (float32 [h, w, 2])."""
    r = np.empty_like(out)
    for y in range(out.shape[0]):
        for x in range(out.shape[1]):
            r[y, x, 0] = out[y, x, 0] * wgt[y, x]
            r[y, x, 1] = out[y, x, 1] * wgt[y, x]
    return r


@nb.njit(cache=True, nogil=True)
def _fill(out, wgt, empty, num, den, eps):
    """One round of the normalised-convolution fill of :func:`invert`, in place: every empty pixel whose box average
    of filled neighbours has weight ``den`` > ``eps`` takes ``num / den`` (float32) and counts as filled; returns how
    many stay empty."""
    left = 0
    for y in range(out.shape[0]):
        for x in range(out.shape[1]):
            if not empty[y, x]:
                continue
            d = den[y, x]
            if d > eps:
                out[y, x, 0] = num[y, x, 0] / d
                out[y, x, 1] = num[y, x, 1] / d
                wgt[y, x] = 1.0
                empty[y, x] = False
            else:
                left += 1
    return left
