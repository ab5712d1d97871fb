"""Kernels of the odometry's exclusion mask (:func:`tracker.odometry.ego_motion.moving_scene_mask`): the pixels
standing out of the table plane, the bounding boxes of their large blobs, and the half-resolution mask enlarged to
the frame's size.

They give exactly the values of the numpy / OpenCV expressions they replace (float32 arithmetic in the same order;
the blobs' areas and boxes as ``cv2.connectedComponentsWithStats`` gives them; the pixels of ``cv2.resize``'s nearest
neighbour at twice the size) at a fraction of their time: the statistics pass of OpenCV's labelling cost 0.7 ms per
half-resolution frame, the labelling alone 0.2 ms; the resize about 0.2 ms per mask.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)
def foreground(depth: np.ndarray, rx: np.ndarray, ry: np.ndarray, n: np.ndarray, offset: np.float32,
               static: np.ndarray, lo: np.float32, hi: np.float32) -> np.ndarray:
    """H×W uint8, 1 where ``lo < depth · dots + offset < hi`` (the height above the table plane, metres; NaN depth is
    never foreground) and ``static`` is 0; ``dots[i, j] = n[0]·rx[j] + (n[1]·ry[i] + n[2])`` (the table normal ``n``
    with the rays of column ``j`` and row ``i``, ``rx`` / ``ry`` their slopes): float32 arithmetic in numpy's order
    of ``depth * ((n[0] * rx)[None, :] + (n[1] * ry + n[2])[:, None]) + offset``, the same values."""
    h, w = depth.shape
    out = np.zeros((h, w), np.uint8)
    col = np.empty(w, np.float32)
    for j in range(w):
        col[j] = n[0] * rx[j]
    for i in range(h):
        row = n[1] * ry[i] + n[2]
        for j in range(w):  # branch-free (NaN depth compares False)
            height = np.float32(depth[i, j] * np.float32(col[j] + row)) + offset
            out[i, j] = (static[i, j] == 0) & (height > lo) & (height < hi)
    return out


@nb.njit(cache=True, nogil=True)
def fill_large_blobs(mask: np.ndarray, labels: np.ndarray, n_labels: int, min_px: int) -> None:
    """Set ``mask`` (uint8, in place) to 1 over the bounding box of every labelled blob (``labels`` 1 …
    ``n_labels`` − 1, as ``cv2.connectedComponents`` gives them; 0 is the background) of at least ``min_px``
    pixels."""
    h, w = labels.shape
    area = np.zeros(n_labels, np.int64)
    u0 = np.full(n_labels, w, np.int64)
    v0 = np.full(n_labels, h, np.int64)
    u1 = np.full(n_labels, -1, np.int64)
    v1 = np.full(n_labels, -1, np.int64)
    for i in range(h):
        for j in range(w):
            k = labels[i, j]
            if k > 0:
                area[k] += 1
                u0[k] = min(u0[k], j)
                u1[k] = max(u1[k], j)
                v0[k] = min(v0[k], i)
                v1[k] = max(v1[k], i)
    for k in range(1, n_labels):
        if area[k] >= min_px:
            mask[v0[k]:v1[k] + 1, u0[k]:u1[k] + 1] = 1


@nb.njit(cache=True, nogil=True)
def enlarge_twice(small: np.ndarray, h: int, w: int) -> np.ndarray:
    """The H×W bool mask whose pixel ``(v, u)`` is ``small[v // 2, u // 2]`` up to twice ``small``'s size and False
    beyond it (a last odd row or column; twice ``small``'s size must not exceed H×W): ``cv2.resize(·,
    INTER_NEAREST)`` to twice the size, then padded, in one pass."""
    sh, sw = small.shape
    out = np.zeros((h, w), np.uint8)
    for i in range(sh):
        r0 = out[2 * i]
        r1 = out[2 * i + 1]
        for j in range(sw):
            x = np.uint8(small[i, j])
            r0[2 * j] = x
            r0[2 * j + 1] = x
        r1[: 2 * sw] = r0[: 2 * sw]
    return out.view(np.bool_)
