"""The thesis's evaluation metrics (hand-tracking spec §10.3, eqs. 7.1–7.9) for one frame.

Boxes are end-exclusive pixel boxes [u0, v0, u1, v1] (the ground truth's and the tracker's output format);
a box's centre is ((u0 + u1 − 1)/2, (v0 + v1 − 1)/2), matching the inclusive-box convention of spec §2.

* e^p = ‖centre(estimate) − centre(ground truth)‖ in px (eq. 7.4);
* F^b = F(B(x), B(χ)), the Dice coefficient of the two boxes (eq. 7.6);
* F^c = F(B(x) ∩ B^c, B(χ) ∩ B^c) with the tracker's colour mask B^c (eq. 7.8); 1 when both sets are empty
  (product choice, spec §10.3).
"""

from __future__ import annotations

import numpy as np


def centre(box) -> np.ndarray:
    u0, v0, u1, v1 = (float(b) for b in box)
    return np.array([(u0 + u1 - 1) / 2.0, (v0 + v1 - 1) / 2.0])


def area(box) -> int:
    return max(int(box[2]) - int(box[0]), 0) * max(int(box[3]) - int(box[1]), 0)


def intersection(a, b) -> list[int]:
    return [max(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), min(a[3], b[3])]


def dice(a, b) -> float:
    """F(H, G) = 2|H ∩ G| / (|H| + |G|) of two boxes (0 when both are empty)."""
    s = area(a) + area(b)
    return 2.0 * area(intersection(a, b)) / s if s > 0 else 0.0


def centre_error(est, gt) -> float:
    return float(np.linalg.norm(centre(est) - centre(gt)))


def colour_f_score(est, gt, mask: np.ndarray) -> float:
    """F^c of two boxes with the full-frame colour mask ``mask`` (H×W, nonzero = skin)."""
    def count(b) -> int:
        if area(b) == 0:
            return 0
        return int(np.count_nonzero(mask[b[1] : b[3], b[0] : b[2]]))

    ne, ng = count(est), count(gt)
    if ne + ng == 0:
        return 1.0
    return 2.0 * count(intersection(est, gt)) / (ne + ng)


def frame_metrics(est, gt, mask: np.ndarray) -> dict[str, float]:
    """``{"e_p", "F_b", "F_c"}`` of one estimate against one ground-truth box."""
    return {"e_p": centre_error(est, gt), "F_b": dice(est, gt), "F_c": colour_f_score(est, gt, mask)}
