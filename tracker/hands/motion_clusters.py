"""k-means motion segmentation of the flow inside the colour mask (hand-tracking spec §3.3, eqs. 6.4–6.5).

Only the flow vectors (u, v) are clustered (no positions), Euclidean distance, N_c clusters. Product choices
(§14.2, tightened for the time budget): the fit uses at most 500 randomly subsampled vectors (spec: 2,000), then
every vector is assigned to its nearest centroid and each centroid is recomputed as the mean of all its vectors
(the cluster's mean flow); the fit is OpenCV's k-means with 2 attempts (spec: 3), the first warm-started from the
previous frame's centroids of the same flow, the other k-means++.
"""

from __future__ import annotations

import cv2
import numpy as np

MAX_FIT = 500
ATTEMPTS = 2


class MotionClusters:
    """Motion segmentations with warm starts kept per flow ``key`` (e.g. "f1", "f2", "b1", "b2")."""

    def __init__(self, n_clusters: int = 4, seed: int = 0) -> None:
        self.n_clusters = int(n_clusters)
        self.rng = np.random.default_rng(seed)
        self._prev: dict[str, np.ndarray] = {}

    def segment(self, flow: np.ndarray, mask: np.ndarray, key: str) -> tuple[np.ndarray, np.ndarray]:
        """(labels int32 [h, w], −1 outside ``mask``; centroids [N_c, 2] float64, mean flow of each cluster, NaN for
        an empty cluster) of the vectors of ``flow`` [h, w, 2] where ``mask`` is set."""
        h, w = mask.shape
        labels = np.full((h, w), -1, np.int32)
        cent = np.full((self.n_clusters, 2), np.nan)
        sel = mask.astype(bool)
        vec = flow[sel].astype(np.float32)
        n = len(vec)
        if n == 0:
            return labels, cent
        k = min(self.n_clusters, n)
        fit = vec if n <= MAX_FIT else vec[self.rng.choice(n, MAX_FIT, replace=False)]
        cv2.setRNGSeed(int(self.rng.integers(1 << 30)))
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 0.01)
        prev = self._prev.get(key)
        if prev is not None and len(prev) == k and len(fit) >= k:
            init = np.argmin(((fit[:, None, :] - prev[None]) ** 2).sum(-1), axis=1).astype(np.int32)[:, None]
            _, _, centers = cv2.kmeans(fit, k, init, crit, ATTEMPTS,
                                        cv2.KMEANS_USE_INITIAL_LABELS | cv2.KMEANS_PP_CENTERS)
        elif len(fit) >= k:
            _, _, centers = cv2.kmeans(fit, k, None, crit, ATTEMPTS, cv2.KMEANS_PP_CENTERS)
        else:
            centers = fit[:k]
        lab = np.argmin(((vec[:, None, :] - centers[None]) ** 2).sum(-1), axis=1)
        labels[sel] = lab
        counts = np.bincount(lab, minlength=k)
        su = np.bincount(lab, weights=vec[:, 0], minlength=k)
        sv = np.bincount(lab, weights=vec[:, 1], minlength=k)
        ok = counts > 0
        cent[:k][ok] = np.stack([su[ok] / counts[ok], sv[ok] / counts[ok]], axis=1)
        self._prev[key] = np.asarray(centers, np.float32)
        return labels, cent

    def reset(self) -> None:
        self._prev.clear()
