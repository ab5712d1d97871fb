"""Prediction stage: every part's particles moved by the dynamic model (spec 4.26) without noise.

The noise-free prediction decides which pixels are evaluated (:func:`tracker.filter.render.evaluated_pixels`);
the noisy propagation of each part happens in its coordinate pass (:mod:`tracker.filter.weigh`).

Two velocity models (``TrackerConfig.velocity_model``):

* ``seed``: each particle carries its own velocity, damped by ``k_v`` every step (eq. 4.26).
* ``constant``: constant velocity with adaptive noise (not in the seed). After every frame each well-seen part's
  velocity is estimated from its final (refined) estimates of this and the previous frame, smoothed
  exponentially (``cv_smoothing``), and given to all its particles; the prediction carries it on with gain
  ``cv_gain`` (< 1: a part that stops is not thrown far). The motion noise of a moving part grows with its speed
  (``cv_noise_gain`` × speed / ``sigma_v``, at most ``cv_noise_max`` times), so parts at rest keep the tight noise
  that makes them precise while fast ones get the spread to follow. Hidden, resting and carried parts have zero
  velocity (the hand carry moves carried ones).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from tracker.filter.motion_model import propagate, propagate_part_into, sample_noise

if TYPE_CHECKING:
    from tracker.filter.particle_filter import MultiObjectTracker


def velocity_gain(cfg) -> float:
    """Factor on the previous velocity in the prediction: ``k_v`` (seed) or ``cv_gain`` (constant velocity)."""
    return cfg.cv_gain if cfg.velocity_model == "constant" else cfg.k_v


def deterministic(trk: MultiObjectTracker, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Particles (p, R, v) of every part propagated with zero noise under the colour input ``u`` (K, 3)."""
    cfg = trk.config
    gain = velocity_gain(cfg)
    n, k = trk.p.shape[0], len(trk.parts)
    p_cur = np.empty_like(trk.p)
    R_cur = np.empty_like(trk.R)
    v_cur = np.empty_like(trk.v)
    zero = np.zeros((n, 6))
    for i in range(k):
        p_cur[:, i], R_cur[:, i], v_cur[:, i] = propagate(trk.p[:, i], trk.R[:, i], trk.v[:, i], u[i], zero,
                                                          gain, cfg.b)
    return p_cur, R_cur, v_cur


def noisy(trk: MultiObjectTracker, p_prev: np.ndarray, R_prev: np.ndarray, v_prev: np.ndarray, u: np.ndarray,
          scale: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One part's particles (N, 3) / (N, 3, 3) / (N, 6) propagated with freshly sampled noise (stds × ``scale``)."""
    cfg = trk.config
    noise = sample_noise(trk.rng, p_prev.shape[0], cfg.sigma_v * scale, cfg.sigma_w * scale, cfg.wide_noise_fraction,
                         cfg.wide_noise_scale)
    return propagate(p_prev, R_prev, v_prev, u, noise, velocity_gain(cfg), cfg.b)


def noisy_into(trk: MultiObjectTracker, rows: np.ndarray, obj: int, u: np.ndarray, scale: float, p_out: np.ndarray,
               R_out: np.ndarray, v_out: np.ndarray) -> None:
    """:func:`noisy` of part ``obj`` from last frame's particles ``rows`` (N,) (``trk.p``, ``trk.R``, ``trk.v``; e.g.
    the frame's resamplings composed), written into column ``obj`` of ``p_out`` (N, K, 3), ``R_out`` (N, K, 3, 3),
    ``v_out`` (N, K, 6): the same noise draws and values as ``p_out[:, obj], R_out[:, obj], v_out[:, obj] =
    noisy(trk, trk.p[rows, obj], trk.R[rows, obj], trk.v[rows, obj], u, scale)`` in one kernel call
    (:func:`~tracker.filter.motion_model.propagate_part_into`)."""
    cfg = trk.config
    noise = sample_noise(trk.rng, rows.shape[0], cfg.sigma_v * scale, cfg.sigma_w * scale, cfg.wide_noise_fraction,
                         cfg.wide_noise_scale)
    propagate_part_into(trk.p, trk.R, trk.v, rows, int(obj), noise, np.asarray(u, np.float64).reshape(3),
                        float(velocity_gain(cfg)), float(cfg.b), p_out, R_out, v_out)


def adaptive_noise(trk: MultiObjectTracker) -> np.ndarray:
    """Per part (K,), the factor on the motion noise from its estimated speed (constant-velocity model; 1 with
    the seed's model)."""
    cfg = trk.config
    if cfg.velocity_model != "constant":
        return np.ones(len(trk.parts))
    speed = np.linalg.norm(trk._est_vel[:, :3], axis=1)
    return np.minimum(1.0 + cfg.cv_noise_gain * speed / max(cfg.sigma_v, 1e-9), cfg.cv_noise_max)


def update_velocities(trk: MultiObjectTracker, poses: dict, seen: np.ndarray) -> None:
    """Constant-velocity model: estimate each part's velocity (per frame: metres, rotation vector in radians,
    camera frame) from its final estimates ``poses`` and the previous frame's; ``seen`` (K,) parts whose estimate
    is supported by the data now (the others get zero velocity). All particles of a part take its velocity."""
    cfg = trk.config
    if cfg.velocity_model != "constant":
        return
    from scipy.spatial.transform import Rotation

    prev = trk._prev_poses
    a = cfg.cv_smoothing
    for i, name in enumerate(trk.names):
        cur = poses[name]
        if prev is None or not seen[i]:
            trk._est_vel[i] = 0.0
        else:
            old = prev[name]
            v = np.concatenate([cur.t - old.t, Rotation.from_matrix(cur.R @ old.R.T).as_rotvec()])
            trk._est_vel[i] = a * v + (1.0 - a) * trk._est_vel[i]
        trk.v[:, i] = trk._est_vel[i]
    trk._prev_poses = dict(poses)
