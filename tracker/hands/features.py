"""Per-frame features of both hand trackers on a region of interest (hand-tracking spec §3, §14.2).

For the step k−1 → k inside the ROI R_k: the colour masks B^c_{k−1}, B^c_k, the four flows f^{f,1}, f^{f,2},
f^{b,1}, f^{b,2}, the four motion segmentations S^{f,α} (on B^c_{k−1}) and S^{b,α} (on B^c_k), and the connected
components (4-connectivity) of B^c_k for the section-6 mode. All arrays are on the ROI's pixel grid; ``roi`` =
(x0, y0, x1, y1), end-exclusive image pixels, gives its place in the image.

A colour component that reaches an ROI edge which is not an image edge is flagged ``cc_cut``: its true extent is
unknown, so it never passes the section-6 test (product choice; the thesis computes components on the whole
image).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from tracker.hands.flow import four_flows
from tracker.hands.motion_clusters import MotionClusters


@dataclass
class HandFeatures:
    roi: tuple[int, int, int, int]
    mprev: np.ndarray
    mcur: np.ndarray
    ff: tuple[np.ndarray, np.ndarray]
    fb: tuple[np.ndarray, np.ndarray]
    labf: tuple[np.ndarray, np.ndarray]
    centf: tuple[np.ndarray, np.ndarray]
    labb: tuple[np.ndarray, np.ndarray]
    centb: tuple[np.ndarray, np.ndarray]
    cc: np.ndarray
    n_comp: int
    cc_area: np.ndarray
    cc_box: np.ndarray
    cc_cut: np.ndarray
    anchors: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    """Palm anchors of the frame (:mod:`tracker.hands.palm_cut`): inclusive boxes [K, 4] in image (working) px."""

    @property
    def origin(self) -> np.ndarray:
        return np.array([self.roi[0], self.roi[1]], float)


def compute_features(prev_grey: np.ndarray, cur_grey: np.ndarray, mprev: np.ndarray, mcur: np.ndarray,
                     roi: tuple[int, int, int, int], image_size: tuple[int, int], clusters: MotionClusters,
                     flow_method: str = "dis", max_side: int = 192, backward: bool = True,
                     flow_cache: dict | None = None) -> HandFeatures:  # fmt: skip
    """Features of the ROI from the full-frame greyscale images and the ROI colour masks (uint8 0/1 of the ROI).

    ``backward=False`` skips the backward segmentations (the Kalman tracker does not use them); ``flow_cache``: the
    caller's optical-flow instances (:func:`tracker.hands.flow.flow`)."""
    x0, y0, x1, y1 = roi
    W, H = image_size
    pg = np.ascontiguousarray(prev_grey[y0:y1, x0:x1])
    cg = np.ascontiguousarray(cur_grey[y0:y1, x0:x1])
    ff1, fb1, ff2, fb2 = four_flows(pg, cg, flow_method, max_side, cache=flow_cache)
    lf1, cf1 = clusters.segment(ff1, mprev, "f1")
    lf2, cf2 = clusters.segment(ff2, mprev, "f2")
    if backward:
        lb1, cb1 = clusters.segment(fb1, mcur, "b1")
        lb2, cb2 = clusters.segment(fb2, mcur, "b2")
    else:
        lb1 = lb2 = np.full(mcur.shape, -1, np.int32)
        cb1 = cb2 = np.full_like(cf1, np.nan)
    cc, n_comp, area, boxes, cut = components(mcur, roi, image_size)
    return HandFeatures(roi, mprev, mcur, (ff1, ff2), (fb1, fb2), (lf1, lf2), (cf1, cf2), (lb1, lb2), (cb1, cb2),
                        cc, n_comp, area, boxes, cut)  # fmt: skip


def components(mask: np.ndarray, roi: tuple[int, int, int, int],
               image_size: tuple[int, int]) -> tuple[np.ndarray, int, np.ndarray, np.ndarray, np.ndarray]:
    """Connected components (4-connectivity) of an ROI mask (uint8 0/1; ``roi`` = (x0, y0, x1, y1) in an image of
    ``image_size`` (W, H) px): labels, component count (without the background, label 0), areas (px), inclusive
    boxes [u0, v0, u1, v1] in ROI px and cut flags (the component touches an ROI side that is not the image's border,
    so the hand may go on beyond it; the background flagged)."""
    x0, y0, x1, y1 = roi
    W, H = image_size
    n, cc, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=4, ltype=cv2.CV_32S)
    h, w = mask.shape
    bx, by, bw, bh = stats[:, 0], stats[:, 1], stats[:, 2], stats[:, 3]
    cut = np.zeros(n, bool)
    if x0 > 0:
        cut |= bx == 0
    if y0 > 0:
        cut |= by == 0
    if x1 < W:
        cut |= bx + bw == w
    if y1 < H:
        cut |= by + bh == h
    cut[0] = True
    boxes = np.stack([bx, by, bx + bw - 1, by + bh - 1], axis=1).astype(np.int64)
    return cc, int(n - 1), stats[:, cv2.CC_STAT_AREA].astype(np.int64), boxes, cut
