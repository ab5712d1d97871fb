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

from tracker.odometry.correspondences import empty_buffers, geometric_terms, photometric_terms
from tracker.odometry.keyframe import Keyframe, KeyframeLevel
from tracker.odometry.odometry_config import OdometryConfig
from tracker.odometry.rgbd_pyramid import PyramidLevel
from tracker.odometry.se3 import exp_se3, invert, log_se3


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


def _huber(r: np.ndarray, k: float) -> np.ndarray:
    a = np.abs(r)
    return np.where(a <= k, 1.0, k / np.maximum(a, 1e-12))


def _tukey(r: np.ndarray, c: float) -> np.ndarray:
    x = np.minimum(np.abs(r) / c, 1.0)
    return (1.0 - x * x) ** 2


def _weights(x: np.ndarray, cfg: OdometryConfig) -> np.ndarray:
    """Robust weights of residuals ``x`` in units of their robust scale."""
    return _tukey(x, cfg.tukey) if cfg.robust == "tukey" else _huber(x, cfg.huber)


SIGMA_SAMPLES = 1024
"""The robust scale is taken from at most this many residuals (an even stride through them): the median of a
thousand is as good a scale estimate as the median of all, at a fraction of the cost (two medians per term and
Gauss-Newton iteration were 40 % of the alignment's time)."""


def _robust_sigma(r: np.ndarray, floor: float) -> float:
    """1.4826 × the median absolute deviation of the residuals ``r`` (at most :data:`SIGMA_SAMPLES` of them, evenly
    strided), not below ``floor``."""
    if r.size == 0:
        return floor
    if r.size > SIGMA_SAMPLES:
        r = r[:: -(-r.size // SIGMA_SAMPLES)]
    return max(floor, 1.4826 * float(np.median(np.abs(r - np.median(r)))))


def _photometric(kl: KeyframeLevel, cur: PyramidLevel, T_ck: np.ndarray):
    """Residuals and Jacobian rows of the photometric term, or None when too few points are seen."""
    n_all = kl.photo_points.shape[0]
    if n_all < 10:
        return None
    ref, val, J = empty_buffers(n_all)
    intr = cur.intrinsics
    n = photometric_terms(kl.photo_points, kl.photo_values, kl.photo_jacobian, T_ck, cur.gray, cur.mask,
                          intr.fx, intr.fy, intr.cx, intr.cy, ref, val, J)
    if n < 10:
        return None
    ref, val, J = ref[:n], val[:n], J[:n]
    # global gain / offset: least squares of ref ≈ a·val + b
    vm, rm = val.mean(), ref.mean()
    var = float(np.mean((val - vm) ** 2))
    a = float(np.clip(np.mean((val - vm) * (ref - rm)) / var, 0.7, 1.3)) if var > 1e-6 else 1.0
    b = rm - a * vm
    return ref - (a * val + b), J


def _geometric(kl: KeyframeLevel, cur: PyramidLevel, T_kc: np.ndarray, T_ck: np.ndarray, max_dist: float):
    """(residuals, Jacobian rows) of the point-to-plane term (or None) and the overlap share."""
    n_all = kl.geo_points.shape[0]
    if n_all < 10:
        return None, 0.0
    r, _, J = empty_buffers(n_all)
    intr = cur.intrinsics
    n, seen = geometric_terms(kl.geo_points, kl.geo_normals, T_ck, T_kc, cur.depth, cur.mask, intr.fx, intr.fy,
                              intr.cx, intr.cy, max_dist, r, J)
    overlap = seen / n_all
    if n < 10:
        return None, overlap
    return (r[:n], J[:n]), overlap


def align(keyframe: Keyframe, current: list[PyramidLevel], T_kc_init: np.ndarray, cfg: OdometryConfig) -> Alignment:
    """Align the current frame's pyramid to ``keyframe`` starting from ``T_kc_init`` (see the module docstring)."""
    T_kc = np.array(T_kc_init, dtype=np.float64)
    T_prior_inv = invert(T_kc)
    prior = np.array([1.0 / cfg.prior_sigma_m**2] * 3 + [1.0 / np.radians(cfg.prior_sigma_deg) ** 2] * 3) \
        if cfg.prior_sigma_m > 0 else None
    total_it = 0
    inliers = 0
    overlap = 0.0
    converged = False
    for lv, n_it in zip(cfg.levels, cfg.iterations, strict=True):
        kl, cur = keyframe.levels[lv], current[lv]
        for _ in range(n_it):
            total_it += 1
            T_ck = invert(T_kc)
            H = np.zeros((6, 6))
            g = np.zeros(6)
            inliers = 0
            photo = _photometric(kl, cur, T_ck) if cfg.photo_weight > 0 else None
            if photo is not None:
                r, J = photo
                s = _robust_sigma(r, cfg.min_photo_sigma)
                w = _weights(r / s, cfg) * (cfg.photo_weight / s**2)
                H += (J * w[:, None]).T @ J
                g += J.T @ (w * r)
                inliers += int(np.count_nonzero(np.abs(r) <= cfg.huber * s))
            geo, overlap = _geometric(kl, cur, T_kc, T_ck, cfg.max_geo_distance)
            if geo is not None:
                r, J = geo
                s = _robust_sigma(r, cfg.min_geo_sigma)
                w = _weights(r / s, cfg) / s**2
                H += (J * w[:, None]).T @ J
                g += J.T @ (w * r)
                inliers += int(np.count_nonzero(np.abs(r) <= cfg.huber * s))
            if inliers < 6:
                break
            if prior is not None:  # weak pull towards the prediction: matters only where the data say nothing
                H[np.diag_indices(6)] += prior
                g += prior * log_se3(T_kc @ T_prior_inv)
            H[np.diag_indices(6)] += 1e-6 * (np.trace(H) / 6.0 + 1e-9)
            try:
                xi = -np.linalg.solve(H, g)
            except np.linalg.LinAlgError:
                break
            T_kc = exp_se3(xi) @ T_kc
            if np.linalg.norm(xi[:3]) < cfg.converged_m and np.linalg.norm(xi[3:]) < cfg.converged_rad:
                converged = True
                break
    return Alignment(T_kc=T_kc, inliers=inliers, overlap=overlap, iterations=total_it, converged=converged)
