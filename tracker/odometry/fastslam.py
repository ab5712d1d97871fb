"""FastSLAM 1.0 over the camera pose with 3-D point landmarks (spec ``camera-localisation.md`` section 5, the
fixed mode with the product adaptations of section 12), vectorised over particles with numpy.

Each particle holds a camera pose (camera → world: rotation ``R``, translation ``t``; metres) and, per landmark,
a 3-D mean ``μ`` (world frame) and 3×3 covariance ``Σ``: one EKF per landmark per particle (Table 3.5.1).

* Motion (section 12 instead of the differential drive, D7/D13 fixed): a 6-DoF random walk (default) or constant
  velocity, ``T ← T · exp((ξ̇ Δt) + n)`` with ``ξ̇`` the estimated body-frame velocity twist (zero for the random
  walk) and ``n`` Gaussian noise (D5: a Gaussian draw of the stated standard deviation) of ``sigma_t`` metres and
  ``sigma_r_deg`` degrees per frame interval (1/30 s), scaled with √(Δt·30). On simulator seeds 0–4 the constant
  velocity model fed back the filter's own jitter and drifted (13 mm against 4 mm ATE over 3 s).
* Measurement (section 12, Cartesian): ``z = Rᵀ(μ − t) + noise`` in the camera frame, so ``H = Rᵀ`` and the
  landmark update is an exact Kalman step (Table 4.2.1): ``S = H Σ Hᵀ + Q``, ``K = Σ Hᵀ S⁻¹``,
  ``μ += K ν``, ``Σ = (I − K H) Σ``. ``Q`` per observation: lateral σ = ``sigma_px`` · z / f, depth σ =
  ``sigma_z0`` + ``sigma_z2`` · z² (not given in the thesis — chosen for a Kinect-type sensor).
* New landmark (Table 4.2.2): ``μ = R z + t``, ``Σ = R Q Rᵀ`` (= H⁻¹ Q H⁻ᵀ); the weight is unchanged.
* Importance weight (eqs 4.2.2.15–21, D4 fixed: correct normaliser, log space): per re-observed landmark
  ``−½ νᵀ S⁻¹ ν − ½ log |2π S|``, the Mahalanobis term capped at ``max_mahalanobis2`` (a mismatch that survived
  the front end costs at most that much).
* Resampling (Table 4.2.3, D9/D10 fixed): stochastic universal sampling, once per frame, only when
  ``N_eff = 1 / Σ w² < resample_fraction · M``.
* Pose output (D9): the weighted mean (translation mean, sign-aligned quaternion mean) or the best particle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


@dataclass(frozen=True)
class FastSlamConfig:
    """Settings of the FastSLAM option (defaults chosen on simulator seeds 0–4; the thesis values are M = 100,
    Q = I₃, 6 features per frame — see the spec's section 10)."""

    n_particles: int = 100
    motion: str = "random_walk"
    sigma_t: float = 0.001
    sigma_r_deg: float = 0.1
    sigma_px: float = 2.0
    sigma_z0: float = 0.002
    sigma_z2: float = 0.006
    max_mahalanobis2: float = 9.0
    resample_fraction: float = 0.5
    estimate: str = "mean"
    max_features: int = 300
    max_new_landmarks: int = 150
    min_tracked: int = 80
    max_landmarks: int = 4000
    inlier_m: float = 0.015
    min_inliers: int = 8

    def __post_init__(self) -> None:
        if self.n_particles < 1:
            raise ValueError("FastSlamConfig: n_particles must be >= 1")
        if self.motion not in ("random_walk", "constant_velocity"):
            raise ValueError(f"FastSlamConfig: motion must be random_walk or constant_velocity, got {self.motion!r}")
        if self.estimate not in ("mean", "best"):
            raise ValueError(f"FastSlamConfig: estimate must be 'mean' or 'best', got {self.estimate!r}")


def sus_indices(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Stochastic universal (low-variance) resampling: particle indices for normalised ``weights``."""
    m = weights.size
    c = np.cumsum(weights)
    c[-1] = 1.0
    u = rng.uniform(0.0, 1.0 / m) + np.arange(m) / m
    return np.searchsorted(c, u, side="left")


class FastSlam1:
    """The particle filter state and its steps (see the module docstring)."""

    def __init__(self, fx: float, config: FastSlamConfig, rng: np.random.Generator) -> None:
        self.cfg = config
        self.fx = float(fx)
        self.rng = rng
        m = config.n_particles
        self.R = np.repeat(np.eye(3)[None], m, axis=0)
        self.t = np.zeros((m, 3))
        self.log_w = np.zeros(m)
        self.mu = np.zeros((m, 0, 3))
        self.sigma = np.zeros((m, 0, 3, 3))

    @property
    def n_landmarks(self) -> int:
        return self.mu.shape[1]

    def weights(self) -> np.ndarray:
        w = np.exp(self.log_w - self.log_w.max())
        return w / w.sum()

    def _q(self, z: np.ndarray) -> np.ndarray:
        """Measurement covariances (n, 3, 3) of camera-frame points ``z`` (n, 3)."""
        depth = np.maximum(z[:, 2], 0.05)
        s_xy = self.cfg.sigma_px * depth / self.fx
        s_z = self.cfg.sigma_z0 + self.cfg.sigma_z2 * depth**2
        q = np.zeros((z.shape[0], 3, 3))
        q[:, 0, 0] = q[:, 1, 1] = s_xy**2
        q[:, 2, 2] = s_z**2
        return q

    def predict(self, twist: np.ndarray, dt: float) -> None:
        """Move every particle by the body-frame velocity ``twist`` ([v, ω] per second) over ``dt`` seconds plus
        Gaussian noise."""
        m = self.R.shape[0]
        scale = np.sqrt(max(dt, 1e-3) * 30.0)
        dv = twist[:3] * dt + self.rng.normal(0.0, self.cfg.sigma_t * scale, (m, 3))
        dw = twist[3:] * dt + self.rng.normal(0.0, np.radians(self.cfg.sigma_r_deg) * scale, (m, 3))
        dR = Rotation.from_rotvec(dw).as_matrix()
        self.t = self.t + np.einsum("mij,mj->mi", self.R, dv)
        self.R = self.R @ dR

    def add_landmarks(self, z: np.ndarray) -> np.ndarray:
        """Add landmarks observed at camera-frame points ``z`` (n, 3); returns their indices."""
        n0 = self.n_landmarks
        mu = np.einsum("mij,nj->mni", self.R, z) + self.t[:, None, :]
        q = self._q(z)
        sig = np.einsum("mij,njk,mlk->mnil", self.R, q, self.R)
        self.mu = np.concatenate([self.mu, mu], axis=1)
        self.sigma = np.concatenate([self.sigma, sig], axis=1)
        return np.arange(n0, n0 + z.shape[0])

    def update(self, z: np.ndarray, idx: np.ndarray) -> None:
        """Kalman-update the landmarks ``idx`` observed at camera-frame points ``z`` (n, 3) and weight the
        particles."""
        if z.shape[0] == 0:
            return
        mu = self.mu[:, idx]  # (m, n, 3)
        sig = self.sigma[:, idx]  # (m, n, 3, 3)
        Rt = np.transpose(self.R, (0, 2, 1))  # H = R^T per particle
        zhat = np.einsum("mij,mnj->mni", Rt, mu - self.t[:, None, :])
        nu = z[None] - zhat
        S = np.einsum("mij,mnjk,mlk->mnil", Rt, sig, Rt) + self._q(z)[None]
        S_inv = np.linalg.inv(S)
        d2 = np.einsum("mni,mnij,mnj->mn", nu, S_inv, nu)
        _, logdet = np.linalg.slogdet(2.0 * np.pi * S)
        self.log_w += np.sum(-0.5 * np.minimum(d2, self.cfg.max_mahalanobis2) - 0.5 * logdet, axis=1)
        K = np.einsum("mnij,mkj,mnkl->mnil", sig, Rt, S_inv)  # Σ Hᵀ S⁻¹
        self.mu[:, idx] = mu + np.einsum("mnij,mnj->mni", K, nu)
        KH = np.einsum("mnij,mjk->mnik", K, Rt)
        self.sigma[:, idx] = sig - np.einsum("mnij,mnjk->mnik", KH, sig)

    def resample_if_needed(self) -> bool:
        """SUS resampling when the effective sample size is low; returns whether it happened."""
        w = self.weights()
        if 1.0 / np.sum(w**2) >= self.cfg.resample_fraction * w.size:
            return False
        idx = sus_indices(w, self.rng)
        self.R, self.t = self.R[idx], self.t[idx]
        self.mu, self.sigma = self.mu[:, :][idx], self.sigma[idx]
        self.log_w = np.zeros(w.size)
        return True

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """Pose (R, t) of the camera in the world: weighted mean or best particle (``config.estimate``)."""
        w = self.weights()
        if self.cfg.estimate == "best":
            b = int(np.argmax(w))
            return self.R[b], self.t[b]
        q = Rotation.from_matrix(self.R).as_quat()
        q *= np.sign(q @ q[int(np.argmax(w))])[:, None]
        qm = (w[:, None] * q).sum(axis=0)
        return Rotation.from_quat(qm / np.linalg.norm(qm)).as_matrix(), (w[:, None] * self.t).sum(axis=0)

    def landmark_means(self) -> np.ndarray:
        """Weighted mean landmark positions (L, 3), world frame."""
        return np.einsum("m,mli->li", self.weights(), self.mu)
