"""Track identity from what moves with a hand besides its skin (product addition, hand-tracking spec §14.3 "track
identifiers are stable over time").

Two hands of one person have the same skin colour, so the colour mask cannot tell them apart where they meet, and
a track may come out of an overlap on the other hand. What surrounds each palm differs: sleeve, cuff, watch. Each
track keeps a colour histogram of the non-skin, non-background pixels of its box expanded by :data:`MARGIN` times
its size on every side (the wrist and sleeve lie there), learnt while the track is isolated and confident. The
histograms decide which lost track a re-acquired hand is, which of two duplicate tracks keeps the hand, and when
two tracks have swapped hands (their ids are exchanged back).

Bins: 8 (Y) × 16 (Cr) × 16 (Cb) of 8-bit YCrCb (OpenCV), once for the pixels left of the palm box's centre and once
for those right of it (each hand's arm comes from its own side, so two sleeves of one colour still differ).
Background bins: those holding more than :data:`BG_FRAC` of the session's first frame (assumed hand-free, as for the
session background colour model); pixels in them are not counted (the table and the parts look the same around both
hands). Similarity: the Bhattacharyya coefficient Σ √(p q) of two normalised histograms, in [0, 1].
"""

from __future__ import annotations

import numba as nb
import numpy as np

N_BINS = 8 * 16 * 16
MARGIN = 0.5
BG_FRAC = 5e-4
MIN_PIXELS = 20
"""Fewer counted pixels than this: no appearance measurement."""
RATE = 0.2
"""Learning rate of a track's histogram (running average over frames)."""
LEARN_MIN_SIM = 0.6
"""An observation less similar than this to a track's histogram is not learnt (the track may be on the other hand:
learning it would make the two hands' models alike and the id swap undecidable)."""
SWAP_MARGIN = 0.2
"""The exchanged assignment must be better by this much (sum of two similarities) to swap ids."""


@nb.njit(cache=True, nogil=True)
def bin_image(ycc: np.ndarray) -> np.ndarray:
    """Bin index (int32) of every pixel of a YCrCb uint8 image [h, w, 3]: (Y >> 5) << 8 | (Cr >> 4) << 4 | Cb >> 4."""
    h, w = ycc.shape[0], ycc.shape[1]
    out = np.empty((h, w), np.int32)
    for y in range(h):
        for x in range(w):
            out[y, x] = ((np.int32(ycc[y, x, 0]) >> 5) << 8) | ((np.int32(ycc[y, x, 1]) >> 4) << 4) | (
                np.int32(ycc[y, x, 2]) >> 4)
    return out


def background_bins(bins: np.ndarray) -> np.ndarray:
    """Bool [N_BINS]: the bins holding more than BG_FRAC of the pixels of a (hand-free) frame's bin image."""
    h = np.bincount(bins.ravel(), minlength=N_BINS).astype(np.float64)
    return h > BG_FRAC * bins.size


def appearance(bins: np.ndarray, skin: np.ndarray, bg: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray | None:
    """Normalised histogram [2·N_BINS] of the non-skin, non-background pixels in the inclusive box (u0, v0, u1, v1)
    expanded by MARGIN × its size on every side (clipped to the image), the pixels left and right of the box centre
    counted apart, or None with fewer than MIN_PIXELS."""
    H, W = bins.shape
    u0, v0, u1, v1 = box
    mx = MARGIN * (u1 - u0 + 1)
    my = MARGIN * (v1 - v0 + 1)
    a0, b0 = max(int(u0 - mx), 0), max(int(v0 - my), 0)
    a1, b1 = min(int(u1 + mx) + 1, W), min(int(v1 + my) + 1, H)
    if a1 <= a0 or b1 <= b0:
        return None
    sub = bins[b0:b1, a0:a1]
    keep = ~skin[b0:b1, a0:a1].astype(bool) & ~bg[sub]
    # the right half (columns right of the box centre) counts in bins N_BINS…2·N_BINS−1: an arm that comes from the
    # right has its sleeve there, one from the left on the other side, whatever their colours
    right = np.arange(a0, a1) > 0.5 * (u0 + u1)
    vals = (sub + np.where(right, N_BINS, 0)[None, :])[keep]
    if len(vals) < MIN_PIXELS:
        return None
    h = np.bincount(vals, minlength=2 * N_BINS).astype(np.float64)
    return h / h.sum()


def similarity(p: np.ndarray | None, q: np.ndarray | None) -> float:
    """Bhattacharyya coefficient of two normalised histograms; 0.5 (undecided) if either is missing."""
    if p is None or q is None:
        return 0.5
    return float(np.sum(np.sqrt(p * q)))


def learn(model: np.ndarray | None, obs: np.ndarray) -> np.ndarray:
    """The running-average update of a track's histogram with one observation."""
    return obs.copy() if model is None else (1.0 - RATE) * model + RATE * obs
