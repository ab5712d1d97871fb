"""The wrist cut: the palm box of a skin component that enters the image with its forearm (hand-tracking spec §14.3;
product extension of the section-6 mode to bare forearms).

Spec §14.3 starts a track on a border-entering component with the pixels within L_hand of the component's far end
from its entry point. The product also uses the same cut while tracking (:func:`palm_anchors`): with a bare forearm
the hand, wrist and forearm form one colour component that reaches the image border, so the thesis's section-6
test (the box must hold ≥ 80 % of its component) never passes (thesis ASL sequence). Every such component longer
than :data:`MIN_ARM_M` yields one "anchor" box per frame, the palm end of the arm; a track's particles
whose predicted box overlaps an anchor (box F-score ≥ :data:`ANCHOR_MIN_F`) take the anchor's box, as particles
that pass the section-6 test take their component's box (:mod:`tracker.hands.particle_filter`); the Kalman
reference uses it as its section-6 observation.

With ``tube`` (``HandTrackerConfig.palm_tube``, product addition) the cut of an arm is not a straight line across
it: the forearm behind the hand is fitted as a tube (its axis and half width, :func:`tube_cut`) and the palm is the
arm's far end without the tube's pixels, so that the box holds the thumb beside the wrist and not the forearm's edge
past it (a straight cut across a diagonal arm does both wrong).

Units: working-resolution pixels (the tracker's downscaled image), inclusive boxes (u0, v0, u1, v1), x right,
y down; depth in metres at full resolution.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba as nb
import numpy as np

from tracker.hands import order_stats
from tracker.hands.track_boxes import border_band, touches_border

MIN_ARM_M = 0.15
"""A border component counts as hand + forearm when its extent from the entry point exceeds this length (m) at the
far end's depth (an adult hand is about 0.19 m long)."""
ANCHOR_MIN_F = 0.3
"""Box F-score a predicted box needs with an anchor to take it."""
TUBE_BEHIND_M = 0.08
"""Length (m) of the forearm piece, just behind the palm's reach, to which the tube of :func:`tube_cut` is fitted."""
TUBE_MIN_PX = 20
"""Fewest pixels of that forearm piece (else the whole arm behind the reach) for a tube fit."""
ANCHOR_INSIDE = 0.8
"""Share of an anchor's area inside a larger predicted box with which that box takes the anchor (a box grown over the
whole arm)."""


@dataclass(frozen=True)
class PalmCut:
    """``box`` inclusive palm box; ``extent`` d_max (px) and ``l_hand`` L_hand (px) of the component; ``border``:
    whether the component touches the image border; ``px_per_m`` f_x / Z̄ in working px per metre."""

    box: tuple[int, int, int, int]
    extent: float
    l_hand: float
    border: bool
    px_per_m: float = 0.0

    @property
    def has_forearm(self) -> bool:
        """Whether the component is longer than a hand (:data:`MIN_ARM_M`)."""
        return self.extent > MIN_ARM_M * self.px_per_m


def palm_cut(comp: np.ndarray, depth: np.ndarray | None, scale: int, focal: float, hand_length_m: float,
             far_frac: float = 0.25, origin: tuple[int, int] = (0, 0),
             image_size: tuple[int, int] | None = None,
             tube: tuple[float, float] | None = None) -> PalmCut:  # fmt: skip
    """Palm of a skin component ``comp`` (bool, working resolution): e = mean of the component's pixels within
    b = 2 full-resolution px of an image edge (its entry point; the centroid if none), d = each pixel's distance from
    e, and the palm is the pixels with d ≥ d_max − L_hand, L_hand = f_x · ``hand_length_m`` / Z̄ in working pixels
    (``focal`` f_x in full-resolution px, ``scale`` the working downscale factor).

    Product choice: Z̄ is the median valid depth (``depth`` in metres, full resolution) of the component's far end
    (the ``far_frac`` of its pixels farthest from e) rather than of the whole component — a bare forearm reaches
    towards the camera and its depth lengthened L_hand about twofold; without depth Z̄ = 0.75 m.

    ``comp`` may be a crop of the working image: ``origin`` (x, y) is its top-left pixel in the image and
    ``image_size`` (w, h) the image's size (default: ``comp``'s own); the box is in image pixels.

    ``tube`` = (reach_m, tip_m): a component longer than a hand (:attr:`PalmCut.has_forearm`) is cut by
    :func:`tube_cut` instead (``hand_length_m`` is then unused for it)."""
    h, w = comp.shape
    if image_size is not None:
        w, h = image_size
    b = border_band(scale)
    xs, ys, e, border = _component_pixels(comp, int(origin[0]), int(origin[1]), b, w, h)
    d = _distances(xs, ys, e[0], e[1])
    z = 0.75
    if depth is not None:
        dz = _far_depths(xs, ys, d, order_stats.quantile(d, 1.0 - far_frac), scale, np.asarray(depth))
        if len(dz):
            z = order_stats.median(dz)
    l_hand = focal / scale * hand_length_m / z
    dmax = float(d.max())
    ppm = focal / scale / z
    sel = None
    if tube is not None and dmax > MIN_ARM_M * ppm:
        sel = tube_cut(xs, ys, e, d, tube[0] * ppm, tube[1] * ppm, TUBE_BEHIND_M * ppm)
    if sel is None:
        sel = d >= dmax - l_hand if dmax > l_hand else np.ones(len(d), bool)
    box = _selected_box(xs, ys, sel)
    return PalmCut(box, dmax, float(l_hand), border, ppm)


def tube_cut(xs: np.ndarray, ys: np.ndarray, e: np.ndarray, d: np.ndarray, reach: float, tip: float,
             behind: float) -> np.ndarray | None:  # fmt: skip
    """The palm pixels (bool per pixel) of an arm's component: pixel coordinates ``xs``, ``ys``, entry point ``e``,
    ``d`` each pixel's distance from e; lengths ``reach``, ``tip`` and ``behind`` in the same pixels. None if no tube
    can be fitted.

    The arm's axis a runs from e to the centroid of the 10 % of its pixels farthest from e; p = each pixel's
    position along a, q across it, p_max the far end. The forearm piece behind the palm's reach (p in
    [p_max − reach − behind, p_max − reach), at least TUBE_MIN_PX pixels; else every pixel behind the reach) gives
    the tube: per 1-px slice of p its middle (q_min + q_max)/2 and half width (q_max − q_min + 1)/2, a least-squares
    line q = α·p + β through the middles of the slices with two or more pixels, radius r = the median half width.
    The palm is the pixels with p ≥ p_max − reach that lie outside the tube (distance to the line > r) or within
    ``tip`` of the far end (p ≥ p_max − tip)."""
    ax, ay = _far_mean(xs, ys, d, order_stats.quantile(d, 0.9))
    a = np.array([ax - e[0], ay - e[1]])
    norm = float(np.hypot(a[0], a[1]))
    if norm < 1e-9:
        return None
    a /= norm
    p, q = _along_across(xs, ys, float(e[0]), float(e[1]), float(a[0]), float(a[1]))
    pmax = float(p.max())
    start = pmax - reach
    lo, cnt, qmin, qmax = _slices(p, q, start, start - behind, TUBE_MIN_PX)
    if len(cnt) == 0:
        return None
    ok = cnt >= 2
    if np.count_nonzero(ok) < 3:
        return None
    pc = lo + np.flatnonzero(ok) + 0.5
    mid = 0.5 * (qmin[ok] + qmax[ok])
    pm, qm = pc.mean(), mid.mean()
    var = float(((pc - pm) ** 2).sum())
    slope = float(((pc - pm) * (mid - qm)).sum()) / var if var > 0 else 0.0
    icpt = qm - slope * pm
    r = order_stats.median(0.5 * (qmax[ok] - qmin[ok] + 1.0))
    sel = _outside_tube(p, q, slope, float(icpt), float(np.sqrt(1.0 + slope * slope)), r, start, pmax - tip)
    return sel if sel.any() else None


def palm_anchors(mask: np.ndarray, depth: np.ndarray | None, scale: int, focal: float, hand_length_m: float,
                 min_area: float, tube: tuple[float, float] | None = None) -> np.ndarray:  # fmt: skip
    """Anchor boxes [K, 4] (float64, inclusive, working px) of the frame's colour mask ``mask`` (uint8 0/1, whole
    working frame): one per 4-connected component of area ≥ ``min_area`` that touches the image border and reaches
    farther than MIN_ARM_M from it. The mask is opened with a 5×5 disk first (isolated false skin pixels on a
    sleeve would otherwise chain into an "arm"). Without ``depth`` there are no anchors: the hand's length in pixels
    would be a guess, and a wrong cut is worse than none. ``tube``: as for :func:`palm_cut`."""
    if depth is None:
        return np.zeros((0, 4))
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5)))
    n, lab, stats, (ox, oy) = cropped_components(mask)
    h, w = mask.shape
    b = border_band(scale)
    out = []
    for i in range(1, n):
        x, y, bw, bh, area = (int(v) for v in stats[i])
        if area < min_area or not touches_border((x, y, x + bw - 1, y + bh - 1), (w, h), b):
            continue
        sub = lab[y - oy : y - oy + bh, x - ox : x - ox + bw] == i
        cut = palm_cut(sub, depth, scale, focal, hand_length_m, origin=(x, y), image_size=(w, h), tube=tube)
        if cut.border and cut.has_forearm:
            out.append(cut.box)
    return np.asarray(out, np.float64).reshape(-1, 4)


def cropped_components(mask: np.ndarray) -> tuple[int, np.ndarray, np.ndarray, tuple[int, int]]:
    """4-connected components of a uint8 mask, labelled only inside the bounding rectangle of its set pixels (its
    top-left corner moved to even coordinates): ``(n, labels, stats, (x0, y0))`` as ``cv2.connectedComponentsWithStats``
    gives them for the whole mask, except that ``labels`` covers the rectangle only (pixel (x, y) of the mask is
    ``labels[y − y0, x − x0]``) and the background's row 0 of ``stats`` describes the rectangle. Components, their
    numbering (raster order of their first pixel) and their rows 1… of ``stats`` (in mask coordinates) are those of
    the whole mask; a mask with hands in a corner costs a fraction of the full labelling."""
    x, y, w, h = cv2.boundingRect(mask)
    if w == 0 or h == 0:
        x = y = 0
        w, h = min(mask.shape[1], 1), min(mask.shape[0], 1)
    x0, y0 = x - (x & 1), y - (y & 1)
    sub = np.ascontiguousarray(mask[y0 : y + h, x0 : x + w])
    n, lab, stats, _ = cv2.connectedComponentsWithStats(sub, connectivity=4, ltype=cv2.CV_32S)
    stats[:, 0] += x0
    stats[:, 1] += y0
    return n, lab, stats, (x0, y0)


def match_anchor(boxes: np.ndarray, anchors: np.ndarray, min_f: float = ANCHOR_MIN_F) -> np.ndarray:
    """For inclusive boxes [N, 4], the index of the anchor with the highest box F-score if it is ≥ ``min_f``; else,
    for a box larger than an anchor that holds ≥ ANCHOR_INSIDE of that anchor's area, that anchor; else −1 ([N]
    int)."""
    if len(anchors) == 0 or len(boxes) == 0:
        return np.full(len(boxes), -1, np.int64)
    a = anchors[None]
    q = np.asarray(boxes, np.float64)[:, None]
    iw = np.minimum(q[..., 2], a[..., 2]) - np.maximum(q[..., 0], a[..., 0]) + 1
    ih = np.minimum(q[..., 3], a[..., 3]) - np.maximum(q[..., 1], a[..., 1]) + 1
    inter = np.clip(iw, 0, None) * np.clip(ih, 0, None)
    sa = (q[..., 2] - q[..., 0] + 1) * (q[..., 3] - q[..., 1] + 1)
    sb = (a[..., 2] - a[..., 0] + 1) * (a[..., 3] - a[..., 1] + 1)
    f = 2 * inter / np.maximum(sa + sb, 1)
    best = f.argmax(axis=1)
    out = np.where(f[np.arange(len(boxes)), best] >= min_f, best, -1)
    # a box grown over a whole arm (e.g. a track started on a hand that had just entered with its forearm) holds the
    # anchor of its palm: the anchor with the largest share of its area inside the box, if that share is high enough
    inside = inter / np.maximum(sb, 1)
    big = inside.argmax(axis=1)
    grown = (out < 0) & (inside[np.arange(len(boxes)), big] >= ANCHOR_INSIDE) & (sa[:, 0] > sb[0, big])
    return np.where(grown, big, out)


def holds_anchor(box: tuple[float, float, float, float], anchor: np.ndarray) -> bool:
    """Whether an inclusive box larger than an anchor holds ≥ ANCHOR_INSIDE of the anchor's area (a box over the
    whole arm)."""
    iw = min(box[2], anchor[2]) - max(box[0], anchor[0]) + 1
    ih = min(box[3], anchor[3]) - max(box[1], anchor[1]) + 1
    sa = (box[2] - box[0] + 1) * (box[3] - box[1] + 1)
    sb = (anchor[2] - anchor[0] + 1) * (anchor[3] - anchor[1] + 1)
    return sa > sb and max(iw, 0) * max(ih, 0) >= ANCHOR_INSIDE * sb


def anchor_state(box: np.ndarray, prev_xy: tuple[float, float]) -> np.ndarray:
    """State (x, y, w, h, x', y') of an anchor box (tight-box convention of spec §6), velocity from ``prev_xy``."""
    u0, v0, u1, v1 = (float(v) for v in box)
    x, y = 0.5 * (u0 + u1), 0.5 * (v0 + v1)
    return np.array([x, y, u1 - u0, v1 - v0, x - prev_xy[0], y - prev_xy[1]])


# ---------------------------------------------------------------- kernels (session 31: the per-pixel passes of
# palm_cut and tube_cut, which were ~40 numpy calls on a component's pixel lists; the same values bit for bit: integer
# sums are exact in float64 whatever their order, every other value is the same IEEE operation per pixel, and the
# sums over a tube's slices stay numpy's)


@nb.njit(cache=True, nogil=True)
def _component_pixels(comp, ox, oy, b, w, h):
    """``(xs, ys, e, border)`` of a component mask ``comp`` (any nonzero set): its pixels' image coordinates (int64,
    row-major as ``np.nonzero`` gives them, plus the origin ``(ox, oy)``), the entry point e (float64 [2]: the mean of
    the pixels within ``b`` px of an edge of the ``w`` × ``h`` image, or of all pixels if none is) and whether some
    pixel is that close to an edge."""
    n = 0
    for y in range(comp.shape[0]):
        for x in range(comp.shape[1]):
            if comp[y, x]:
                n += 1
    xs = np.empty(n, np.int64)
    ys = np.empty(n, np.int64)
    k = 0
    sx = sy = ex = ey = ne = 0
    for y in range(comp.shape[0]):
        for x in range(comp.shape[1]):
            if comp[y, x]:
                X, Y = x + ox, y + oy
                xs[k] = X
                ys[k] = Y
                k += 1
                sx += X
                sy += Y
                if X < b or Y < b or X >= w - b or Y >= h - b:
                    ex += X
                    ey += Y
                    ne += 1
    e = np.empty(2)
    if ne > 0:
        e[0] = ex / ne
        e[1] = ey / ne
    else:
        e[0] = sx / n
        e[1] = sy / n
    return xs, ys, e, ne > 0


@nb.njit(cache=True, nogil=True)
def _distances(xs, ys, e0, e1):
    """``np.hypot(xs - e0, ys - e1)`` (float64)."""
    d = np.empty(xs.shape[0])
    for i in range(xs.shape[0]):
        d[i] = np.hypot(xs[i] - e0, ys[i] - e1)
    return d


@nb.njit(cache=True, nogil=True)
def _far_depths(xs, ys, d, thr, scale, depth):
    """The valid (finite, > 0) full-resolution depths under the working pixels with ``d >= thr`` (each pixel's
    (x·s, y·s), clipped to the image), in pixel order."""
    H, W = depth.shape
    out = np.empty(xs.shape[0], depth.dtype)
    k = 0
    for i in range(xs.shape[0]):
        if d[i] >= thr:
            v = depth[min(ys[i] * scale, H - 1), min(xs[i] * scale, W - 1)]
            if np.isfinite(v) and v > 0:
                out[k] = v
                k += 1
    return out[:k]


@nb.njit(cache=True, nogil=True)
def _far_mean(xs, ys, d, thr):
    """Mean x and y of the pixels with ``d >= thr`` (exactly numpy's for integer coordinates)."""
    sx = sy = 0.0
    n = 0
    for i in range(xs.shape[0]):
        if d[i] >= thr:
            sx += xs[i]
            sy += ys[i]
            n += 1
    return sx / n, sy / n


@nb.njit(cache=True, nogil=True)
def _along_across(xs, ys, e0, e1, a0, a1):
    """Each pixel's position p along the unit axis (a0, a1) from e and q across it (float64)."""
    p = np.empty(xs.shape[0])
    q = np.empty(xs.shape[0])
    for i in range(xs.shape[0]):
        dx = xs[i] - e0
        dy = ys[i] - e1
        p[i] = dx * a0 + dy * a1
        q[i] = dy * a0 - dx * a1
    return p, q


@nb.njit(cache=True, nogil=True)
def _slices(p, q, start, back, min_px):
    """The forearm piece's 1-px slices of :func:`tube_cut`: the piece is the pixels with ``back <= p < start`` if
    there are ``min_px`` of them, else those with ``p < start`` (empty arrays if fewer); per slice floor(p) − lo
    (lo = the lowest floor(p)), its pixel count and its lowest and highest q. Returns (lo, cnt, qmin, qmax)."""
    n1 = 0
    n2 = 0
    for i in range(p.shape[0]):
        if p[i] < start:
            n2 += 1
            if p[i] >= back:
                n1 += 1
    wide = n1 < min_px
    if wide and n2 < min_px:
        return 0, np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    lo = np.iinfo(np.int64).max
    hi = np.iinfo(np.int64).min
    for i in range(p.shape[0]):
        if p[i] < start and (wide or p[i] >= back):
            f = np.int64(np.floor(p[i]))
            lo = min(lo, f)
            hi = max(hi, f)
    n = hi - lo + 1
    cnt = np.zeros(n, np.int64)
    qmin = np.full(n, np.inf)
    qmax = np.full(n, -np.inf)
    for i in range(p.shape[0]):
        if p[i] < start and (wide or p[i] >= back):
            j = np.int64(np.floor(p[i])) - lo
            cnt[j] += 1
            qmin[j] = min(qmin[j], q[i])
            qmax[j] = max(qmax[j], q[i])
    return lo, cnt, qmin, qmax


@nb.njit(cache=True, nogil=True)
def _outside_tube(p, q, slope, icpt, norm, r, start, tip_from):
    """The palm pixels: ``p >= start`` and (distance |q − (slope·p + icpt)| / norm from the tube's axis > ``r`` or
    ``p >= tip_from``)."""
    sel = np.empty(p.shape[0], np.bool_)
    for i in range(p.shape[0]):
        sel[i] = p[i] >= start and (np.abs(q[i] - (slope * p[i] + icpt)) / norm > r or p[i] >= tip_from)
    return sel


@nb.njit(cache=True, nogil=True)
def _selected_box(xs, ys, sel):
    """(min x, min y, max x, max y) of the selected pixels (at least one)."""
    x0 = y0 = np.iinfo(np.int64).max
    x1 = y1 = np.iinfo(np.int64).min
    for i in range(xs.shape[0]):
        if sel[i]:
            x0 = min(x0, xs[i])
            y0 = min(y0, ys[i])
            x1 = max(x1, xs[i])
            y1 = max(y1, ys[i])
    return int(x0), int(y0), int(x1), int(y1)
