"""Tracking several parts that share one colour from user-drawn boxes (the seed's Algorithm 2 with the errata
of spec section 2.4 fixed). Pixels; boxes are (x, y, w, h) with (x, y) the top-left corner, half-open extents.

Per frame:

1. M2 = shared-range mask, opened then closed (4×4); blobs = its 8-connected components of at least
   ``min_blob_area`` px (the regions of the external contours; connected components give their pixels directly).
2. Each part predicts its box top-left p* = p + v and computes, for every blob, the overlap area of the
   predicted box with the blob's bounding box (clamped at 0, both axes correct).
3. A part overlapping no blob is occluded: its box is moved to p* − (g, g), grown by 2g per axis (capped at
   ``max_box``, keeping its centre) and its velocity damped, v ← k_v'·v (the algorithm, not the prose's "stay in
   place"). Otherwise the part joins the blob it overlaps most.
4. A blob claimed by one part gives it its bounding box plus the margin a; the velocity becomes
   v ← k_v'·v + (1 − k_v')·(p_new − p_old).
5. A blob claimed by n > 1 parts is split by k-means (``cv2.kmeans``) on its pixel coordinates into n clusters,
   initialised with each pixel labelled by the nearest predicted box centre (deterministic, and the clusters
   start where the parts are expected); each part then gets, greedily by increasing distance over all
   (part, cluster) pairs, the closest cluster not yet taken (predicted box centre to cluster centroid).
6. Blobs claimed by nobody are ignored (other objects, not-yet-claimed distractors).

Output per part (:class:`~tracker.color_detection.ColorDetection`): ``center`` = the new box centre, ``bbox`` the
box, ``area`` the pixel area of its blob / cluster, ``score`` = the fraction of that blob's bounding box covered
by the predicted box (1 = the part is exactly where it was predicted), halved for a split blob; occluded parts
have ``center=None``, ``score=0`` and ``bbox`` = their grown box.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import cv2
import numpy as np

from tracker.color_detection import KERNEL_SIZE, ColorDetection, _check_rgb, clean_mask
from tracker.hsv_range import HSVRange


@dataclass(frozen=True)
class SameColorSettings:
    """Parameters of :class:`SameColorTracker` (pixels at the image's own resolution; per processed frame).

    Defaults chosen by the experiment in ``benchmarks/bench_perception.py`` (see benchmarks/results/perception.md).
    """

    growth: float = 2.0
    """g: pixels added per side per frame while a part is occluded."""
    margin: float = 2.0
    """a: pixels added around a blob's bounding box."""
    velocity_factor: float = 0.5
    """k_v': weight of the previous velocity (the prose's update rate c = 1 − k_v')."""
    max_box: int = 160
    """Largest box side (pixels) a growing occluded box may reach."""
    min_blob_area: int = 20
    """Blobs smaller than this (px) are ignored."""
    kmeans_iters: int = 10
    kmeans_eps: float = 0.5
    kmeans_attempts: int = 1
    kernel_size: int = KERNEL_SIZE
    split_score_factor: float = 0.5
    """Score multiplier for parts whose position comes from a k-means split."""


@dataclass
class _Track:
    p: np.ndarray  # top-left (x, y), float
    s: np.ndarray  # size (w, h), float
    v: np.ndarray  # velocity of the top-left corner, px/frame

    @property
    def center(self) -> np.ndarray:
        return self.p + self.s / 2.0

    def box(self) -> tuple[int, int, int, int]:
        return (int(round(self.p[0])), int(round(self.p[1])), int(round(self.s[0])), int(round(self.s[1])))


def _overlap(px: float, py: float, w: float, h: float, bx: int, by: int, bw: int, bh: int) -> float:
    ox = min(px + w, bx + bw) - max(px, bx)
    oy = min(py + h, by + bh) - max(py, by)
    return max(ox, 0.0) * max(oy, 0.0)


class SameColorTracker:
    """Algorithm 2 (corrected): identities of same-coloured parts from user-drawn initial boxes."""

    def __init__(self, hsv_range: HSVRange, settings: SameColorSettings | None = None) -> None:
        if not isinstance(hsv_range, HSVRange):
            raise ValueError(f"SameColorTracker needs an HSVRange, got {type(hsv_range).__name__}")
        self.range = hsv_range
        self.settings = settings or SameColorSettings()
        self._tracks: dict[str, _Track] = {}
        self.last_mask: np.ndarray | None = None

    # ----------------------------------------------------------------------------- state
    def init_boxes(self, boxes: Mapping[str, tuple[float, float, float, float]]) -> None:
        """Start tracking: part name → box (x, y, w, h) drawn by the user (zero velocity)."""
        if not boxes:
            raise ValueError("SameColorTracker.init_boxes: give at least one box")
        tracks = {}
        for name, b in boxes.items():
            try:
                x, y, w, h = (float(v) for v in b)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"SameColorTracker: box of {name!r} must be (x, y, w, h), got {b!r}") from exc
            if not (w > 0 and h > 0) or not all(np.isfinite((x, y, w, h))):
                raise ValueError(f"SameColorTracker: box of {name!r} must have positive width and height, got {b!r}")
            tracks[name] = _Track(np.array([x, y]), np.array([w, h]), np.zeros(2))
        self._tracks = tracks

    @property
    def boxes(self) -> dict[str, tuple[int, int, int, int]]:
        """Current boxes (x, y, w, h) per part."""
        return {n: t.box() for n, t in self._tracks.items()}

    @property
    def velocities(self) -> dict[str, tuple[float, float]]:
        return {n: (float(t.v[0]), float(t.v[1])) for n, t in self._tracks.items()}

    # ----------------------------------------------------------------------------- helpers
    def _cap(self, p: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m = float(self.settings.max_box)
        c = p + s / 2.0
        s = np.minimum(s, m)
        return c - s / 2.0, s

    def _assign(self, name: str, pred_p: np.ndarray, x0: float, y0: float, x1: float, y1: float) -> None:
        """Set the part's box to pixel bbox [x0, x1] × [y0, y1] (inclusive) plus the margin; update velocity."""
        st = self.settings
        t = self._tracks[name]
        a = st.margin
        p_new = np.array([x0 - a, y0 - a], float)
        s_new = np.array([x1 + 1 + a, y1 + 1 + a], float) - p_new
        p_new, s_new = self._cap(p_new, s_new)
        kv = st.velocity_factor
        t.v = kv * t.v + (1.0 - kv) * (p_new - t.p)
        t.p, t.s = p_new, s_new

    # ----------------------------------------------------------------------------- update
    def update(self, rgb: np.ndarray) -> dict[str, ColorDetection]:
        """Process one RGB uint8 frame; returns a detection per part (see the module docstring)."""
        if not self._tracks:
            raise RuntimeError("SameColorTracker.update: call init_boxes() first")
        _check_rgb(rgb, "SameColorTracker")
        st = self.settings
        hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
        mask = clean_mask(self.range.mask(hsv), st.kernel_size)
        self.last_mask = mask
        n_lab, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
        blobs = [i for i in range(1, n_lab) if stats[i, cv2.CC_STAT_AREA] >= st.min_blob_area]

        claims: dict[int, list[str]] = {}
        preds: dict[str, np.ndarray] = {}
        overlap_of: dict[str, float] = {}
        out: dict[str, ColorDetection] = {}
        for name, t in self._tracks.items():
            p_star = t.p + t.v
            preds[name] = p_star
            best, best_a = -1, 0.0
            for i in blobs:
                bx, by, bw, bh = (int(v) for v in stats[i, :4])
                a = _overlap(p_star[0], p_star[1], t.s[0], t.s[1], bx, by, bw, bh)
                if a > best_a:
                    best, best_a = i, a
            if best < 0:  # occluded: move to the prediction, grow, damp the velocity
                g = st.growth
                t.p, t.s = self._cap(p_star - g, t.s + 2.0 * g)
                t.v = st.velocity_factor * t.v
                out[name] = ColorDetection(name, None, 0.0, 0.0, t.box(), None)
            else:
                claims.setdefault(best, []).append(name)
                bw, bh = stats[best, cv2.CC_STAT_WIDTH], stats[best, cv2.CC_STAT_HEIGHT]
                overlap_of[name] = best_a / float(max(1, bw * bh))

        for i, names in claims.items():
            bx, by, bw, bh, area = (int(v) for v in stats[i, :5])
            if len(names) == 1:
                name = names[0]
                self._assign(name, preds[name], bx, by, bx + bw - 1, by + bh - 1)
                out[name] = self._detection(name, overlap_of[name], area)
                continue
            # several parts claim one blob: k-means on its pixel coordinates
            ys, xs = np.nonzero(labels[by : by + bh, bx : bx + bw] == i)
            xy = np.stack([xs + bx, ys + by], axis=1).astype(np.float32)
            k = len(names)
            centres = np.array([preds[n] + self._tracks[n].s / 2.0 for n in names], np.float32)
            if len(xy) < k:
                init = np.zeros(len(xy), np.int32)
            else:
                d2 = ((xy[:, None, :] - centres[None, :, :]) ** 2).sum(axis=2)
                init = np.argmin(d2, axis=1).astype(np.int32)
                missing = set(range(k)) - set(np.unique(init).tolist())
                for j, m in enumerate(sorted(missing)):  # every cluster needs at least one pixel
                    init[j] = m
            crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, st.kmeans_iters, st.kmeans_eps)
            _, lab, cen = cv2.kmeans(
                xy, k, init.reshape(-1, 1).copy(), crit, st.kmeans_attempts, cv2.KMEANS_USE_INITIAL_LABELS
            )
            lab = lab.ravel()
            pairs = sorted(
                (float(np.hypot(*(centres[a] - cen[c]))), a, c) for a in range(k) for c in range(k)
            )
            used_p: set[int] = set()
            used_c: set[int] = set()
            for _, a, c in pairs:
                if a in used_p or c in used_c:
                    continue
                used_p.add(a)
                used_c.add(c)
                name = names[a]
                sel = xy[lab == c]
                if len(sel) == 0:
                    continue
                x0, y0 = sel.min(axis=0)
                x1, y1 = sel.max(axis=0)
                self._assign(name, preds[name], float(x0), float(y0), float(x1), float(y1))
                t = self._tracks[name]
                out[name] = ColorDetection(
                    name,
                    (float(t.center[0]), float(t.center[1])),
                    float(min(1.0, overlap_of[name]) * st.split_score_factor),
                    float(len(sel)),
                    t.box(),
                    None,
                )
        return {n: out.get(n, ColorDetection(n, None, 0.0, 0.0, self._tracks[n].box(), None)) for n in self._tracks}

    def _detection(self, name: str, frac: float, area: int) -> ColorDetection:
        t = self._tracks[name]
        return ColorDetection(
            name, (float(t.center[0]), float(t.center[1])), float(min(1.0, frac)), float(area), t.box(), None
        )
