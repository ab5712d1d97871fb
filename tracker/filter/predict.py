"""Prediction stage: every part's particles moved by the dynamic model (spec 4.26) without noise.

The noise-free prediction decides which pixels are evaluated (:func:`tracker.filter.render.evaluated_pixels`);
the noisy propagation of each part happens in its coordinate pass (:mod:`tracker.filter.weigh`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from tracker.filter.motion_model import propagate, sample_noise

if TYPE_CHECKING:
    from tracker.filter.particle_filter import MultiObjectTracker


def deterministic(trk: MultiObjectTracker, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Particles (p, R, v) of every part propagated with zero noise under the colour input ``u`` (K, 3)."""
    cfg = trk.config
    n, k = trk.p.shape[0], len(trk.parts)
    p_cur = np.empty_like(trk.p)
    R_cur = np.empty_like(trk.R)
    v_cur = np.empty_like(trk.v)
    zero = np.zeros((n, 6))
    for i in range(k):
        p_cur[:, i], R_cur[:, i], v_cur[:, i] = propagate(trk.p[:, i], trk.R[:, i], trk.v[:, i], u[i], zero,
                                                          cfg.k_v, cfg.b)
    return p_cur, R_cur, v_cur


def noisy(trk: MultiObjectTracker, p_prev: np.ndarray, R_prev: np.ndarray, v_prev: np.ndarray, u: np.ndarray,
          scale: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One part's particles (N, 3) / (N, 3, 3) / (N, 6) propagated with freshly sampled noise (stds × ``scale``)."""
    cfg = trk.config
    noise = sample_noise(trk.rng, p_prev.shape[0], cfg.sigma_v * scale, cfg.sigma_w * scale, cfg.wide_noise_fraction,
                         cfg.wide_noise_scale)
    return propagate(p_prev, R_prev, v_prev, u, noise, cfg.k_v, cfg.b)
