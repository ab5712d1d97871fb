"""Dense RGB-D alignment of a frame to a keyframe: robust Gauss-Newton on a point-to-plane term and a photometric
term, coarse to fine over the image pyramid.

Unknown: ``T_kc``, the current camera's pose in the keyframe's camera frame (4×4, current → keyframe), updated by
a left perturbation ``T_kc ← exp(ξ) T_kc`` (twist ``ξ = [v, ω]``, metres / radians).

* Photometric (inverse compositional, after Baker & Matthews 2004 and Kerl et al., "Robust odometry estimation for
  RGB-D cameras", ICRA 2013): residual ``r = I_k(p) − (a·I_c(π(T_kc⁻¹ p)) + b)`` for keyframe points ``p``,
  Jacobian precomputed on the keyframe (:mod:`.keyframe`); ``a, b`` a global gain and offset refitted every
  iteration (lighting drift).
* Point-to-plane with projective association (Chen & Medioni 1992; Newcombe et al., KinectFusion 2011):
  ``r = n_k · (T_kc q − p)``, ``q`` the current frame's point at the pixel where ``p`` projects.

Each term is divided by its robust scale (1.4826 × median absolute residual of at most ``SIGMA_SAMPLES`` of them,
floored) and Huber-weighted; correspondences that fall on masked pixels of the current frame (hands, moving parts) are
dropped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tracker.odometry.gauss_newton import gauss_newton_level
from tracker.odometry.keyframe import Keyframe
from tracker.odometry.odometry_config import OdometryConfig
from tracker.odometry.rgbd_pyramid import PyramidLevel
from tracker.odometry.se3 import invert


@dataclass
class Alignment:
    """Result of :func:`align`: ``T_kc`` (4×4), ``inliers`` (correspondences with a Huber weight of 1 at the finest
    level, both terms), ``overlap`` (share of the keyframe's geometric points seen in the current frame),
    ``iterations`` run, and ``converged``."""

    T_kc: np.ndarray
    inliers: int
    overlap: float
    iterations: int
    converged: bool


SIGMA_SAMPLES = 1024
"""The robust scale is taken from at most this many residuals (an even stride through them): the median of a
thousand is as good a scale estimate as the median of all, at a fraction of the cost."""


def align(keyframe: Keyframe, current: list[PyramidLevel], T_kc_init: np.ndarray, cfg: OdometryConfig) -> Alignment:
    """Align the current frame's pyramid to ``keyframe`` starting from ``T_kc_init`` (see the module docstring)."""
    T_kc = np.array(T_kc_init, dtype=np.float64)
    T_prior_inv = invert(T_kc)
    prior = np.array([1.0 / cfg.prior_sigma_m**2] * 3 + [1.0 / np.radians(cfg.prior_sigma_deg) ** 2] * 3) \
        if cfg.prior_sigma_m > 0 else np.zeros(6)
    tukey = cfg.robust == "tukey"
    threshold = cfg.tukey if tukey else cfg.huber
    total_it, inliers, overlap, converged = 0, 0, 0.0, False
    for lv, n_it in zip(cfg.levels, cfg.iterations, strict=True):
        kl, cur = keyframe.levels[lv], current[lv]
        i = cur.intrinsics
        try:
            T_kc, it, inliers, overlap, converged = gauss_newton_level(
                T_kc, n_it, kl.photo_points, kl.photo_values, kl.photo_jacobian, kl.geo_points, kl.geo_normals,
                cur.gray, cur.depth, cur.mask, i.fx, i.fy, i.cx, i.cy, cfg.photo_weight, cfg.min_photo_sigma,
                cfg.min_geo_sigma, cfg.max_geo_distance, SIGMA_SAMPLES, tukey, threshold, cfg.huber, prior,
                T_prior_inv, cfg.converged_m, cfg.converged_rad)
        except np.linalg.LinAlgError:  # a singular system: no pose from this frame (too few inliers to count)
            return Alignment(T_kc=T_kc, inliers=0, overlap=overlap, iterations=total_it, converged=False)
        total_it += it
    return Alignment(T_kc=T_kc, inliers=inliers, overlap=overlap, iterations=total_it, converged=converged)
