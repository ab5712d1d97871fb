"""The seed's front end (spec section 4, with its fixes): AKAZE features of the grey image, lifted to 3-D with the
registered depth, and matched to the landmark database by descriptor.

* Detection: OpenCV's AKAZE with default parameters (MLDB binary descriptors, 61 bytes), masked pixels
  (hands, parts) excluded. OpenCV 5 has AKAZE in the contrib package (``cv2.xfeatures2d``), OpenCV 4 in main.
* 3-D lookup (section 4.3, D2 fixed): the depth at the keypoint's rounded pixel of the *same* frame; a point
  counts when its depth is finite, positive and below ``MAX_DEPTH_M`` (the thesis's "< 10 m").
* Matching (section 4.1, D3 fixed): brute force with the Hamming norm, k = 2 nearest neighbours, Lowe's ratio
  test 0.8; duplicates of a landmark keep the best (smallest distance) match (D11 fixed).
* Verification (section 12, "3-D–3-D rigid fit check" instead of the homography, which holds only for the table
  plane): RANSAC over 3-point rigid fits (Kabsch) between the matched landmarks' world positions and the
  features' camera-frame points; matches farther than ``inlier_m`` from the best fit are dropped.

Camera frame: x right, y down, z forward; metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from tracker.geometry.camera import Intrinsics

MAX_DEPTH_M = 10.0
"""Largest usable feature depth, metres (thesis: each coordinate < 10 m)."""
RATIO = 0.8
"""Lowe ratio test threshold (thesis)."""


def create_akaze():
    """OpenCV's AKAZE detector with default parameters (main module in OpenCV 4, contrib in OpenCV 5)."""
    make = getattr(cv2, "AKAZE_create", None)
    if make is None:
        xf = getattr(cv2, "xfeatures2d", None)
        make = getattr(xf, "AKAZE_create", None) if xf is not None else None
    if make is None:
        raise RuntimeError("AKAZE is not available in this OpenCV build: install opencv-contrib-python-headless "
                           "(it replaces opencv-python-headless)")
    return make()


@dataclass
class Features:
    """Features of one frame that have depth: pixel ``uv`` (N, 2), camera-frame ``points`` (N, 3) metres and binary
    ``descriptors`` (N, 61) uint8."""

    uv: np.ndarray
    points: np.ndarray
    descriptors: np.ndarray

    def __len__(self) -> int:
        return int(self.points.shape[0])


class AkazeFrontEnd:
    """Detects AKAZE features with depth and matches them to stored landmark descriptors."""

    def __init__(self, intrinsics: Intrinsics, max_features: int = 400) -> None:
        self.intrinsics = intrinsics
        self.max_features = int(max_features)
        self._akaze = create_akaze()
        self._matcher = cv2.BFMatcher(cv2.NORM_HAMMING)

    def detect(self, rgb: np.ndarray, depth: np.ndarray, mask: np.ndarray | None = None) -> Features:
        """Features of an RGB uint8 image with registered depth (metres, NaN invalid); ``mask`` True = exclude."""
        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        allowed = None if mask is None else np.where(mask, 0, 255).astype(np.uint8)
        kps, desc = self._akaze.detectAndCompute(gray, allowed)
        if desc is None or not kps:
            return Features(np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 61), np.uint8))
        order = np.argsort([-k.response for k in kps])[: self.max_features]
        uv = np.array([kps[i].pt for i in order], np.float64)
        desc = desc[order]
        h, w = depth.shape
        ui = np.clip(np.rint(uv[:, 0]).astype(int), 0, w - 1)
        vi = np.clip(np.rint(uv[:, 1]).astype(int), 0, h - 1)
        z = depth[vi, ui].astype(np.float64)
        ok = np.isfinite(z) & (z > 0) & (z < MAX_DEPTH_M)
        pts = self.intrinsics.backproject(ui[ok], vi[ok], z[ok])
        return Features(uv[ok], pts.reshape(-1, 3), desc[ok])

    def match(self, features: Features, descriptors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(feature_idx, landmark_idx)`` pairs passing the ratio test, one per landmark (the best)."""
        if len(features) == 0 or descriptors.shape[0] < 2:
            return np.zeros(0, int), np.zeros(0, int)
        knn = self._matcher.knnMatch(features.descriptors, descriptors, k=2)
        best: dict[int, tuple[float, int]] = {}
        for pair in knn:
            if len(pair) < 2:
                continue
            m, n = pair
            if m.distance < RATIO * n.distance and (m.trainIdx not in best or m.distance < best[m.trainIdx][0]):
                best[m.trainIdx] = (m.distance, m.queryIdx)
        lm = np.array(sorted(best), int)
        fi = np.array([best[k][1] for k in lm], int)
        return fi, lm


def kabsch(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation minimising ``Σ |R src + t − dst|²`` (Kabsch / Umeyama without scale)."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    U, _, Vt = np.linalg.svd((src - cs).T @ (dst - cd))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, cd - R @ cs


def rigid_inliers(world: np.ndarray, cam: np.ndarray, inlier_m: float, rng: np.random.Generator,
                  iterations: int = 100) -> np.ndarray:
    """Boolean inlier mask of 3-D–3-D matches under the best RANSAC rigid fit (``cam ≈ R world + t``)."""
    n = world.shape[0]
    if n < 3:
        return np.zeros(n, bool)
    best = np.zeros(n, bool)
    for _ in range(iterations):
        idx = rng.choice(n, 3, replace=False)
        R, t = kabsch(world[idx], cam[idx])
        inl = np.linalg.norm(world @ R.T + t - cam, axis=1) < inlier_m
        if inl.sum() > best.sum():
            best = inl
            if best.sum() > 0.9 * n:
                break
    if best.sum() >= 3:  # refit on all inliers once
        R, t = kabsch(world[best], cam[best])
        best = np.linalg.norm(world @ R.T + t - cam, axis=1) < inlier_m
    return best
