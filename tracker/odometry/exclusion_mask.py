"""Masks of what must not define the camera's ego-motion: hands and parts (which move). True = exclude.

Sources: a hand's pixel box (the simulator's ground truth ``hand_box`` ``[u0, v0, u1, v1]``, end-exclusive, or a
hand detector's), and the colour detector's per-part masks (:meth:`ColorDetector.masks`), dilated by ``margin``
pixels so that part edges, shadows and depth halos are excluded too.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import cv2
import numpy as np

PART_MARGIN_PX = 6
"""Dilation of part masks, pixels (about a cube edge's depth halo and shadow at 0.6–0.9 m)."""


def exclusion_mask(shape: tuple[int, int], hand_box: Sequence[int] | None = None,
                   part_masks: Iterable[np.ndarray] = (), margin: int = PART_MARGIN_PX) -> np.ndarray:
    """H×W bool mask: True inside ``hand_box`` (grown by ``margin``) and on the dilated ``part_masks`` (any
    non-zero pixel)."""
    h, w = shape
    out = np.zeros((h, w), np.uint8)
    for m in part_masks:
        m = np.asarray(m)
        if m.shape != (h, w):
            raise ValueError(f"exclusion_mask: part mask shape {m.shape} differs from the image {(h, w)}")
        out |= (m > 0).astype(np.uint8)
    if margin > 0 and out.any():
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1, 2 * margin + 1))
        out = cv2.dilate(out, k)
    if hand_box is not None:
        u0, v0, u1, v1 = (int(x) for x in hand_box)
        out[max(0, v0 - margin):min(h, v1 + margin), max(0, u0 - margin):min(w, u1 + margin)] = 1
    return out.astype(bool)
