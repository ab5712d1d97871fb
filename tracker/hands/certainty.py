"""Tracking without uncertainty (hand-tracking spec §6, eqs. 6.54–6.58), shared by both trackers.

From a previous state x_{k−1} two predictions x̂^α (α = 1, 2) move the box by the forward PMC centroid c^α and
scale it by the ratio means r^{·,α}; for each, the colour component of B^c_k covering most of the predicted box
is found and the fraction of that component inside the box computed; the better α wins. If that fraction is
≥ τ^d = 0.8 the state is the tight box of the component (w = u_max − u_min, h = v_max − v_min), velocity = new
centre − old centre. Components cut by the ROI edge never pass (see :mod:`tracker.hands.features`), nor components
whose box overlaps the prediction with a box F-score below :data:`MIN_OVERLAP` (product safeguard against
jumping onto the other hand).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from tracker.hands.box_stats import box_of, dominant_component

TAU_D = 0.8
MIN_OVERLAP = 0.5
"""Product safeguard (not in the thesis): the certain box must have box F-score ≥ 0.5 with the prediction."""


@nb.njit(cache=True, nogil=True)
def certain_state(x, y, w, h, cent, ratio, cc, n_comp, cc_area, cc_box, cc_cut, ox, oy, tau_d):
    """(passed, state [6]) for previous centre/size (x, y, w, h) in image coordinates; ``cent`` [2, 2] = forward
    PMC centroids c^α (NaN if undefined), ``ratio`` [2, 2] = (r^x, r^y) per α; ROI origin (ox, oy)."""
    out = np.zeros(6)
    best = -1.0
    best_lab = 0
    best_x = best_y = best_w = best_h = 0.0
    for a in range(2):
        cx = cent[a, 0]
        cy = cent[a, 1]
        if not (np.isfinite(cx) and np.isfinite(cy)):
            continue
        u0, v0, u1, v1 = box_of(x + cx - ox, y + cy - oy, ratio[a, 0] * w, ratio[a, 1] * h)
        lab, cnt = dominant_component(u0, v0, u1, v1, cc, n_comp)
        if lab == 0:
            continue
        frac = cnt / cc_area[lab]
        if frac > best:
            best = frac
            best_lab = lab
            best_x = x + cx
            best_y = y + cy
            best_w = ratio[a, 0] * w
            best_h = ratio[a, 1] * h
    if best < tau_d or best_lab == 0 or cc_cut[best_lab]:
        return False, out
    b = cc_box[best_lab]
    # product safeguard: the component's box must overlap the winning prediction (box F-score ≥ MIN_OVERLAP), so
    # that a track does not jump onto another hand's isolated component next to it
    p0, p1, p2, p3 = box_of(best_x - ox, best_y - oy, best_w, best_h)
    iw = min(p2, b[2]) - max(p0, b[0]) + 1
    ih = min(p3, b[3]) - max(p1, b[1]) + 1
    inter = max(iw, 0) * max(ih, 0)
    tot = (p2 - p0 + 1) * (p3 - p1 + 1) + (b[2] - b[0] + 1) * (b[3] - b[1] + 1)
    if 2.0 * inter < MIN_OVERLAP * tot:
        return False, out
    nx = 0.5 * (b[0] + b[2]) + ox
    ny = 0.5 * (b[1] + b[3]) + oy
    out[0] = nx
    out[1] = ny
    out[2] = b[2] - b[0]
    out[3] = b[3] - b[1]
    out[4] = nx - x
    out[5] = ny - y
    return True, out
