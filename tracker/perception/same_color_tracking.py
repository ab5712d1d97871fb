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
6. Blobs claimed by nobody: the seed ignores them, so a part whose box lost its cube (e.g. the hand carried
   the cube away faster than the box follows) is never found again. Extension (``reacquire``, on by default):
   before step 3 grows the occluded boxes, occluded parts take over unclaimed blobs of at least
   ``reacquire_area_ratio`` × their typical area within ``reacquire_px``, nearest first (box centre to blob
   centroid); the velocity is reset (a jump is not a motion) and the score is halved.

Output per part (:class:`ColorDetection`): ``center`` = the new box centre, ``bbox`` the
box, ``area`` the pixel area of its blob / cluster, ``score`` = the fraction of that blob's bounding box covered
by the predicted box (1 = the part is exactly where it was predicted), halved for a split blob; occluded parts
have ``center=None``, ``score=0`` and ``bbox`` = their grown box.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import cv2
import numpy as np

from tracker.perception.color_detection import KERNEL_SIZE, ColorDetection, _check_rgb, clean_mask
from tracker.perception.hsv_range import HSVRange


@dataclass(frozen=True)
class SameColorSettings:
    """Parameters of :class:`SameColorTracker` (pixels at the image's own resolution; per processed frame).

    Defaults chosen by the experiment in ``benchmarks/bench_perception.py`` (see benchmarks/results/perception.md):
    a sweep of g ∈ {0, 1, 2, 4}, a ∈ {0, 5}, k_v' ∈ {0.5, 0.8}, with and without re-acquisition, on five
    simulated sequences (2250 frames at 15 fps) with all cubes re-hued to one red; g = 1, a = 5, k_v' = 0.5 with
    re-acquisition gave the highest fraction of visible part-frames with the correct identity (0.78, vs 0.74 for
    the best setting without re-acquisition). Neighbouring settings differ by a few percent.
    """

    growth: float = 1.0
    """g: pixels added per side per frame while a part is occluded."""
    margin: float = 5.0
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
    """Score multiplier for parts whose position comes from a k-means split or a re-acquisition."""
    split_area_ratio: float = 0.0
    """Area gate (extension, off by default: it lowered the identity-correct fraction in the experiment). When
    > 0, a blob claimed by n parts is split among m = min(n, round(blob area / typical part area)) of them (at
    least 1) when its area is below this fraction of the claimants' summed areas (the claimants with the lowest
    IoU of predicted box and blob bounding box are treated as occluded), and an occluded part may also join a
    claimed blob big enough for one more part."""
    reacquire: bool = True
    """Occluded parts take over unclaimed blobs, nearest first (extension: the seed leaves |T_i| = 0 blobs
    unused, so a part lost once is never found again)."""
    reacquire_px: float = 400.0
    """Largest box-centre to blob-centroid distance for a re-acquisition, pixels."""
    reacquire_area_ratio: float = 0.3
    """A re-acquired blob must have at least this fraction of the part's typical area."""


@dataclass
class _Track:
    p: np.ndarray  # top-left (x, y), float
    s: np.ndarray  # size (w, h), float
    v: np.ndarray  # velocity of the top-left corner, px/frame
    area: float = 0.0  # typical blob area of the part (running mean over single-blob frames), px

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

    def _assign(self, name: str, x0: float, y0: float, x1: float, y1: float, area: float | None,
                jump: bool = False) -> None:
        """Set the part's box to pixel bbox [x0, x1] × [y0, y1] (inclusive) plus the margin (line 14); update the
        velocity (line 15, not after a re-acquisition jump) and, for single-blob frames, the typical area."""
        st = self.settings
        t = self._tracks[name]
        a = st.margin
        p_new = np.array([x0 - a, y0 - a], float)
        s_new = np.array([x1 + 1 + a, y1 + 1 + a], float) - p_new
        p_new, s_new = self._cap(p_new, s_new)
        if not jump:
            kv = st.velocity_factor
            t.v = kv * t.v + (1.0 - kv) * (p_new - t.p)
        t.p, t.s = p_new, s_new
        if area is not None and area > 0:
            t.area = float(area) if t.area <= 0 else 0.8 * t.area + 0.2 * float(area)

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
        n_lab, labels, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
        blobs = [i for i in range(1, n_lab) if stats[i, cv2.CC_STAT_AREA] >= st.min_blob_area]

        # lines 2-12: predicted boxes, overlap with every blob's bounding box, claims
        claims: dict[int, list[str]] = {}
        preds: dict[str, np.ndarray] = {}
        frac_of: dict[str, float] = {}
        iou_of: dict[str, float] = {}
        occluded: list[str] = []
        for name, t in self._tracks.items():
            p_star = t.p + t.v
            preds[name] = p_star
            best, best_a = -1, 0.0
            for i in blobs:
                bx, by, bw, bh = (int(v) for v in stats[i, :4])
                a = _overlap(p_star[0], p_star[1], t.s[0], t.s[1], bx, by, bw, bh)
                if a > best_a:
                    best, best_a = i, a
            if best < 0:
                occluded.append(name)
            else:
                claims.setdefault(best, []).append(name)
                bw, bh = int(stats[best, cv2.CC_STAT_WIDTH]), int(stats[best, cv2.CC_STAT_HEIGHT])
                frac_of[name] = best_a / float(max(1, bw * bh))
                iou_of[name] = best_a / float(t.s[0] * t.s[1] + bw * bh - best_a)

        # extension: occluded parts take over unclaimed blobs, or blobs big enough to hold one more part,
        # nearest first (box centre to blob centroid)
        rejoined: set[str] = set()
        if st.reacquire and occluded:
            pairs = []
            for name in occluded:
                t = self._tracks[name]
                c = preds[name] + t.s / 2.0
                for i in blobs:
                    d = float(np.hypot(*(cents[i] - c)))
                    area = float(stats[i, cv2.CC_STAT_AREA])
                    if d > st.reacquire_px or area < st.reacquire_area_ratio * t.area:
                        continue
                    if i in claims:
                        held = sum(self._tracks[n].area for n in claims[i])
                        if t.area <= 0 or st.split_area_ratio <= 0 or area < st.split_area_ratio * (held + t.area):
                            continue
                    pairs.append((i in claims, d, name, i))
            used_b: set[int] = set()
            for _, _, name, i in sorted(pairs):  # free blobs first, then by distance
                if name in rejoined or i in used_b:
                    continue
                rejoined.add(name)
                used_b.add(i)
                claims.setdefault(i, []).append(name)
                bw, bh = int(stats[i, cv2.CC_STAT_WIDTH]), int(stats[i, cv2.CC_STAT_HEIGHT])
                t = self._tracks[name]
                t.v = np.zeros(2)  # a jump is not a velocity
                preds[name] = cents[i] - t.s / 2.0  # the k-means split starts from the blob's centroid
                frac_of[name] = st.split_score_factor
                iou_of[name] = 0.0
            occluded = [n for n in occluded if n not in rejoined]

        out: dict[str, ColorDetection] = {}
        for i, names in claims.items():
            bx, by, bw, bh, area = (int(v) for v in stats[i, :5])
            if len(names) > 1:  # too small for all its claimants? keep the best-overlapping ones
                areas = [self._tracks[n].area for n in names]
                if all(a > 0 for a in areas) and area < st.split_area_ratio * sum(areas):
                    m = int(min(len(names), max(1, round(area / float(np.median(areas))))))
                    keep = sorted(names, key=lambda n: -iou_of[n])[:m]
                    occluded += [n for n in names if n not in keep]
                    names = keep
            if len(names) == 1:  # lines 13-15
                name = names[0]
                self._assign(name, bx, by, bx + bw - 1, by + bh - 1, area, jump=name in rejoined)
                score = frac_of[name] * (st.split_score_factor if name in rejoined else 1.0)
                out[name] = self._detection(name, score, area)
            else:  # lines 16-18
                self._split(names, preds, labels, i, (bx, by, bw, bh), frac_of, out)

        # lines 9-10: occluded parts move to the prediction, grow, damp their velocity
        for name in occluded:
            t = self._tracks[name]
            g = st.growth
            t.p, t.s = self._cap(preds[name] - g, t.s + 2.0 * g)
            t.v = st.velocity_factor * t.v
            out[name] = ColorDetection(name, None, 0.0, 0.0, t.box(), None)
        return {n: out.get(n, ColorDetection(n, None, 0.0, 0.0, self._tracks[n].box(), None)) for n in self._tracks}

    def _split(self, names, preds, labels, label, bbox, frac_of, out) -> None:
        """k-means split of one blob among ``names`` (lines 16-18)."""
        st = self.settings
        bx, by, bw, bh = bbox
        ys, xs = np.nonzero(labels[by : by + bh, bx : bx + bw] == label)
        xy = np.stack([xs + bx, ys + by], axis=1).astype(np.float32)
        k = len(names)
        centres = np.array([preds[n] + self._tracks[n].s / 2.0 for n in names], np.float32)
        if len(xy) < k:
            for n in names:
                out[n] = ColorDetection(n, None, 0.0, 0.0, self._tracks[n].box(), None)
            return
        d2 = ((xy[:, None, :] - centres[None, :, :]) ** 2).sum(axis=2)
        init = np.argmin(d2, axis=1).astype(np.int32)
        missing = sorted(set(range(k)) - set(np.unique(init).tolist()))
        for j, m in enumerate(missing):  # every cluster needs at least one pixel
            init[j] = m
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, st.kmeans_iters, st.kmeans_eps)
        _, lab, cen = cv2.kmeans(xy, k, init.reshape(-1, 1).copy(), crit, st.kmeans_attempts,
                                 cv2.KMEANS_USE_INITIAL_LABELS)
        lab = lab.ravel()
        pairs = sorted((float(np.hypot(*(centres[a] - cen[c]))), a, c) for a in range(k) for c in range(k))
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
            self._assign(name, float(x0), float(y0), float(x1), float(y1), None)
            t = self._tracks[name]
            out[name] = ColorDetection(
                name,
                (float(t.center[0]), float(t.center[1])),
                float(min(1.0, frac_of[name]) * st.split_score_factor),
                float(len(sel)),
                t.box(),
                None,
            )

    def _detection(self, name: str, frac: float, area: int) -> ColorDetection:
        t = self._tracks[name]
        return ColorDetection(
            name, (float(t.center[0]), float(t.center[1])), float(min(1.0, frac)), float(area), t.box(), None
        )
