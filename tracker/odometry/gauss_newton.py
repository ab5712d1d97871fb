"""Numba Gauss-Newton loop of the dense alignment on one pyramid level (see :mod:`.dense_alignment` for the
formulation): each iteration adds the photometric and point-to-plane terms to the normal equations
(:mod:`.correspondences`), a weak prior if asked, solves, and updates ``T_kc ← exp(ξ) T_kc``. Compiled as one
function so that an iteration costs the kernels' time only (the numpy/Python glue of invert, exp, solve was about
60 µs per iteration, a quarter of an iteration at the half-resolution level).

Twists ``ξ = [v, ω]`` (metres, radians); 4×4 transforms; ``T_kc`` current camera → keyframe camera.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from tracker.odometry.correspondences import geometric_system, photometric_system, symmetrise
from tracker.odometry.se3 import exp_twist, invert_rigid, log_twist


@nb.njit(cache=True, nogil=True)
def gauss_newton_level(T_kc, n_it, photo_points, photo_values, photo_jacobian, geo_points, geo_normals, gray, depth,
                       mask, fx, fy, cx, cy, photo_weight, min_photo_sigma, min_geo_sigma, max_geo_distance,
                       sigma_samples, tukey, threshold, huber, prior, T_prior_inv, converged_m, converged_rad):
    """At most ``n_it`` iterations on one level from ``T_kc``. ``prior``: the diagonal of the prior's information
    (6, zeros = none) about ``T_prior_inv⁻¹``. Returns ``(T_kc, iterations, inliers, overlap, converged)``; it stops
    early on convergence (update below ``converged_m`` and ``converged_rad``), fewer than 6 inliers or a singular
    system."""
    n_photo = photo_points.shape[0] if photo_weight > 0 else 0
    n_geo = geo_points.shape[0]
    ref = np.empty(n_photo)
    val = np.empty(n_photo)
    J = np.empty((n_photo, 6))
    r_geo = np.empty(n_geo)
    J_geo = np.empty((n_geo, 6))
    H = np.zeros((6, 6))
    g = np.zeros(6)
    use_prior = prior.sum() > 0
    it = 0
    inliers = 0
    overlap = 0.0
    converged = False
    for _ in range(n_it):
        it += 1
        T_ck = invert_rigid(T_kc)
        H[:] = 0.0
        g[:] = 0.0
        inliers = 0
        if n_photo >= 10:
            inliers += photometric_system(photo_points, photo_values, photo_jacobian, T_ck, gray, mask, fx, fy, cx,
                                          cy, min_photo_sigma, sigma_samples, photo_weight, tukey, threshold, huber,
                                          ref, val, J, H, g)
        overlap = 0.0
        if n_geo >= 10:
            inl, seen = geometric_system(geo_points, geo_normals, T_ck, T_kc, depth, mask, fx, fy, cx, cy,
                                         max_geo_distance, min_geo_sigma, sigma_samples, tukey, threshold, huber,
                                         r_geo, J_geo, H, g)
            inliers += inl
            overlap = seen / n_geo
        if inliers < 6:
            break
        symmetrise(H)
        if use_prior:  # weak pull towards the prediction: matters only where the data say nothing
            e = log_twist(T_kc @ T_prior_inv)
            for k in range(6):
                H[k, k] += prior[k]
                g[k] += prior[k] * e[k]
        reg = 1e-6 * ((H[0, 0] + H[1, 1] + H[2, 2] + H[3, 3] + H[4, 4] + H[5, 5]) / 6.0 + 1e-9)
        for k in range(6):
            H[k, k] += reg
        if not np.all(np.isfinite(H)) or not np.all(np.isfinite(g)):
            break
        xi = -np.linalg.solve(H, g)
        T_kc = exp_twist(xi) @ T_kc
        if np.sqrt(xi[0] ** 2 + xi[1] ** 2 + xi[2] ** 2) < converged_m and \
                np.sqrt(xi[3] ** 2 + xi[4] ** 2 + xi[5] ** 2) < converged_rad:
            converged = True
            break
    return T_kc, it, inliers, overlap, converged
