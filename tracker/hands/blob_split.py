"""Splitting one colour component between two hand tracks (product addition to hand-tracking spec §6, §14.4).

When two hands touch or overlap, their skin forms one 4-connected colour component. The section-6 test of either
track (:mod:`tracker.hands.certainty`) then passes on the union and both boxes grow over both hands. Before the
filter steps, :func:`split_shared_components` gives each of two tracks that follow hands of their own its part of
such a shared component: every pixel of the component goes to the track whose predicted centre (the previous
estimate moved by its velocity) is nearer (plain Euclidean distance: a distance scaled by each track's own box size
let the smaller box lose pixels, shrink and lose more, frame after frame), and the second track's pixels get a new
component label. The section-6 mode and the re-seeding then see two components, one per hand; the colour mask itself
(and so the likelihood) is unchanged. A component whose box is not clearly larger than both predicted boxes
(:data:`SPLIT_GROWTH`) is left whole: one hand is then mostly hidden behind the other, and a split would hand the
hidden hand's track a slice of the visible one (on tuning seeds 0–4 of ``hands-s2`` this cost two tracks their
hands; without the condition the mean F̄^b was 0.63, with it 0.72, unsplit 0.69).

Units: working-resolution pixels; states (x, y, w, h, x', y') in image coordinates; the component image ``cc`` and
the component boxes are in region-of-interest (ROI) coordinates, origin ``feats.roi[:2]``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from tracker.hands.box_stats import box_area, box_of, dominant_component
from tracker.hands.features import HandFeatures

SPLIT_GROWTH = 1.3
"""A shared component is split only if its box is this many times larger than both predicted boxes."""


def split_shared_components(feats: HandFeatures, states: list[np.ndarray], pairs: list[tuple[int, int]],
                            two_hands: Callable[[int], bool] | None = None) -> int:  # fmt: skip
    """Split, in place, every colour component of ``feats`` that is the dominant component of both predicted boxes
    of a pair of tracks (indices into ``states``, each a state [6] at k−1 in image coordinates) between the two;
    returns the number of components split. Both parts must keep at least one pixel, else nothing changes.
    ``two_hands(label)``: whether a component is too large to be one hand (None: any may be two)."""
    if feats.n_comp == 0 or not pairs:
        return 0
    ox, oy = feats.roi[0], feats.roi[1]
    pred = [np.asarray(s, float) for s in states]
    boxes = [box_of(p[0] + p[4] - ox, p[1] + p[5] - oy, p[2], p[3]) for p in pred]
    n_split = 0
    for i, j in pairs:
        li, _ = dominant_component(*boxes[i], feats.cc, feats.n_comp)
        lj, _ = dominant_component(*boxes[j], feats.cc, feats.n_comp)
        if li == 0 or li != lj:
            continue
        if box_area(feats.cc_box[li]) < SPLIT_GROWTH * max(box_area(boxes[i]), box_area(boxes[j])):
            continue  # no bigger than one hand's box: one hand mostly hidden behind the other, nothing to split
        if two_hands is not None and not two_hands(li):
            continue  # could be one hand: two tracks on one hand must stay duplicates (and one of them end)
        if _split(feats, li, pred[i], pred[j]):
            n_split += 1
    return n_split


def _split(feats: HandFeatures, lab: int, a: np.ndarray, b: np.ndarray) -> bool:
    """Give the pixels of component ``lab`` nearer to predicted state ``b``'s centre than to ``a``'s a new label."""
    ox, oy = feats.roi[0], feats.roi[1]
    u0, v0, u1, v1 = (int(v) for v in feats.cc_box[lab])
    sub = feats.cc[v0 : v1 + 1, u0 : u1 + 1]
    vs, us = np.nonzero(sub == lab)
    x, y = us + (u0 + ox), vs + (v0 + oy)

    def dist(p: np.ndarray) -> np.ndarray:
        return (x - p[0] - p[4]) ** 2 + (y - p[1] - p[5]) ** 2

    to_b = dist(b) < dist(a)
    nb_ = int(np.count_nonzero(to_b))
    if nb_ == 0 or nb_ == len(to_b):
        return False
    new = feats.n_comp + 1
    sub[vs[to_b], us[to_b]] = new  # a view into feats.cc
    feats.n_comp = new
    feats.cc_area = np.append(feats.cc_area, nb_)
    feats.cc_area[lab] -= nb_
    boxes = np.vstack([feats.cc_box, np.zeros((1, 4), feats.cc_box.dtype)])
    for label, sel in ((lab, ~to_b), (new, to_b)):
        boxes[label] = (us[sel].min() + u0, vs[sel].min() + v0, us[sel].max() + u0, vs[sel].max() + v0)
    feats.cc_box = boxes
    feats.cc_cut = np.append(feats.cc_cut, feats.cc_cut[lab])
    return True


def two_means(points: np.ndarray, iterations: int = 10, max_points: int = 2000) -> list[np.ndarray] | None:
    """2-means of pixel positions [N, 2] (Euclidean), started from the two extreme points along their principal
    axis; fitted on at most ``max_points`` evenly spaced points, then every point assigned; the two parts, or None
    for fewer than 2 points."""
    if len(points) < 2:
        return None
    fit = points[:: max(1, len(points) // max_points)]
    centred = fit - fit.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    t = centred @ vt[0]
    c = np.stack([fit[int(np.argmin(t))], fit[int(np.argmax(t))]]).astype(np.float64)
    for _ in range(iterations):
        near = ((fit[:, None, :] - c[None]) ** 2).sum(axis=2).argmin(axis=1)
        if near.min() == near.max():
            return None
        c = np.stack([fit[near == 0].mean(axis=0), fit[near == 1].mean(axis=0)])
    near = ((points[:, None, :] - c[None]) ** 2).sum(axis=2).argmin(axis=1)
    parts = [points[near == 0], points[near == 1]]
    return parts if len(parts[0]) and len(parts[1]) else None
