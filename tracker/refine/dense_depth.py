"""Dense-depth Gauss-Newton refinement of one part's pose (spec ``depth-refinement.md``).

The particle filter proposes, this polishes. For a part at its current estimate ``T = (R, t)`` (body → camera,
metres) the model points are the part's visible surface points at that estimate (rendered, with normals:
:mod:`tracker.refine.surface_render`), stored in the body frame. Each correspondence iteration projects every
model point ``x_i = R p_i + t`` into the depth image, reads the measured point ``q_i`` at that pixel, and keeps the
pair when the depth is valid, the pixel is allowed (the part's colour blob, when it has one), the measurement is
not more than ``occlusion_m`` in front of ``x_i`` (something occludes it: a hand, another part) and
``‖x_i − q_i‖`` is below the iteration's threshold (coarse to fine). With the point-to-plane residual
``r_i = m_iᵀ(x_i − q_i)`` (``m_i = R n_i``) and a twist ``ξ = (ω, v)`` that rotates about the part's centre ``c``
(``x ← c + exp(ω)(x − c) + v``, better conditioned than a rotation about the camera), the Jacobian is
``J_i = [((x_i − c) × m_i)ᵀ, m_iᵀ]``. Robust Huber weights with a depth-noise scale ``σ(z) = σ₀ + k z²``, a
Tikhonov prior ``Λ = diag(λ_r I₃, λ_t I₃)`` (keeps directions the data do not pin down, e.g. sliding along a
single visible face, where the filter put them), and the 6×6 normal equations solved by Cholesky.

Returns the refined pose with health figures (valid fraction, median |r|) and the data's information matrix
``Σ wJᵀJ/σ²`` (its inverse approximates the pose covariance in the twist coordinates about ``c``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from tracker.geometry.camera import Intrinsics


@dataclass(frozen=True)
class RefineSettings:
    """Parameters of :func:`refine_pose` (metres, radians, pixels)."""

    thresholds: tuple[float, ...] = (0.03, 0.015, 0.008, 0.005)
    """Largest accepted ``‖x − q‖`` per correspondence iteration (coarse to fine)."""
    updates_per_iteration: int = 2
    """Gauss-Newton updates per correspondence iteration."""
    occlusion_m: float = 0.03
    """A measurement this much in front of the model point means something occludes it: the pair is rejected."""
    huber_k: float = 1.345
    """Huber threshold in units of σ."""
    sigma0: float = 0.0008
    """Depth noise at zero range (m)."""
    sigma_z2: float = 0.0015
    """Depth noise growth (1/m): σ(z) = σ₀ + k z² (structured light / stereo grow roughly with z²)."""
    lambda_rot: float = 25.0
    """Tikhonov weight on the rotation update (1/rad²)."""
    lambda_trans: float = 2500.0
    """Tikhonov weight on the translation update (1/m²)."""
    min_points: int = 25
    """Fewer valid pairs than this: the refinement is not healthy."""
    min_valid_fraction: float = 0.35
    """A smaller share of model points with a valid, unoccluded pair: not healthy."""
    min_observed_fraction: float = 0.7
    """Or healthy when at least this share of the observable model points (valid depth, allowed pixel, nothing in
    front) matched, and at least twice ``min_points`` did: a part partly hidden by a hand."""
    max_points: int = 700
    """Model points used per part (evenly thinned when there are more)."""
    stop_step: float = 1e-6
    """Stop early when the update's norm (rad and m) falls below this."""


@dataclass
class RefineResult:
    """Outcome of :func:`refine_pose`: ``R``, ``t`` the refined pose (body → camera); health figures."""

    R: np.ndarray
    t: np.ndarray
    healthy: bool
    n_model: int
    n_valid: int
    valid_fraction: float
    median_residual: float
    information: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))
    reason: str = ""
    n_behind: int = 0
    """Model points whose measured depth lies well behind them (free space where the model has surface)."""

    @property
    def score(self) -> float:
        """Support of the pose by the depth: matched model points minus twice the free-space violations."""
        return float(self.n_valid - 2 * self.n_behind)


def _huber(r_over_s: np.ndarray, k: float) -> np.ndarray:
    a = np.abs(r_over_s)
    return np.where(a <= k, 1.0, k / np.maximum(a, 1e-12))


def refine_pose(
    depth: np.ndarray,
    intrinsics: Intrinsics,
    points: np.ndarray,
    normals: np.ndarray,
    R: np.ndarray,
    t: np.ndarray,
    center: np.ndarray,
    settings: RefineSettings | None = None,
    allowed: np.ndarray | None = None,
) -> RefineResult:
    """Refine the pose ``(R, t)`` of a part whose visible model points are ``points`` with ``normals`` (body frame,
    (M, 3) each) against ``depth`` (H×W float metres, NaN or 0 = none). ``center``: the body-frame point the
    rotation update turns about. ``allowed``: optional H×W bool mask of pixels the part may claim (its colour blob;
    pixels of hands or other parts left out)."""
    cfg = settings or RefineSettings()
    R = np.asarray(R, np.float64).copy()
    t = np.asarray(t, np.float64).copy()
    pts = np.asarray(points, np.float64)
    nrm = np.asarray(normals, np.float64)
    if pts.shape[0] > cfg.max_points:
        sel = np.linspace(0, pts.shape[0] - 1, cfg.max_points).round().astype(np.int64)
        pts, nrm = pts[sel], nrm[sel]
    m_total = pts.shape[0]
    h, w = depth.shape
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    prior = np.diag([cfg.lambda_rot] * 3 + [cfg.lambda_trans] * 3)
    info = np.zeros((6, 6))
    n_valid, n_observable, med = 0, 0, float("nan")
    if m_total < cfg.min_points:
        return RefineResult(R, t, False, m_total, 0, 0.0, med, info, "too few visible model points")
    for thr in cfg.thresholds:
        for _ in range(cfg.updates_per_iteration):
            x = pts @ R.T + t
            m = nrm @ R.T
            z = x[:, 2]
            front = z > 1e-3
            zs = np.where(front, z, 1.0)
            u = np.rint(fx * x[:, 0] / zs + cx).astype(np.int64)
            v = np.rint(fy * x[:, 1] / zs + cy).astype(np.int64)
            ok = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
            uc, vc = np.where(ok, u, 0), np.where(ok, v, 0)
            d = depth[vc, uc].astype(np.float64)
            ok &= np.isfinite(d) & (d > 0)
            if allowed is not None:
                ok &= allowed[vc, uc]
            ok &= d >= z - cfg.occlusion_m
            n_observable = int(ok.sum())  # depth there, the part may claim the pixel, nothing in front
            d = np.where(ok, d, 0.0)
            q = np.stack([(uc - cx) / fx * d, (vc - cy) / fy * d, d], axis=1)
            diff = x - q
            ok &= np.einsum("ij,ij->i", diff, diff) < thr * thr
            n_valid = int(ok.sum())
            if n_valid < cfg.min_points:
                return RefineResult(R, t, False, m_total, n_valid, n_valid / m_total, med, info,
                                    f"only {n_valid} valid depth pairs")
            xv, mv, dv = x[ok], m[ok], diff[ok]
            r = np.einsum("ij,ij->i", mv, dv)
            c = R @ center + t
            J = np.hstack([np.cross(xv - c, mv), mv])
            sig = cfg.sigma0 + cfg.sigma_z2 * xv[:, 2] ** 2
            wgt = _huber(r / sig, cfg.huber_k) / sig**2
            info = (J * wgt[:, None]).T @ J
            g = J.T @ (wgt * r)
            try:
                L = np.linalg.cholesky(info + prior)
                xi = -np.linalg.solve(L.T, np.linalg.solve(L, g))
            except np.linalg.LinAlgError:
                return RefineResult(R, t, False, m_total, n_valid, n_valid / m_total, med, info, "singular system")
            Rw = Rotation.from_rotvec(xi[:3]).as_matrix()
            t = c + Rw @ (t - c) + xi[3:]
            R = Rw @ R
            med = float(np.median(np.abs(r)))
            if np.linalg.norm(xi) < cfg.stop_step:
                break
    n_behind = _count_behind(depth, intrinsics, pts @ R.T + t, cfg.thresholds[-1] * 2.0)
    frac = n_valid / m_total
    # supported: enough of the model matched, or (partly hidden by a hand or another part) most of what can be seen
    healthy = frac >= cfg.min_valid_fraction or (
        n_valid >= 2 * cfg.min_points and n_valid >= cfg.min_observed_fraction * max(n_observable, 1))
    return RefineResult(R, t, healthy, m_total, n_valid, frac, med, info,
                        "" if healthy else f"only {frac:.0%} of the visible model points matched the depth", n_behind)


def _count_behind(depth: np.ndarray, intrinsics: Intrinsics, x: np.ndarray, margin: float) -> int:
    """How many camera-frame points ``x`` (M, 3) project onto a measurement more than ``margin`` behind them."""
    h, w = depth.shape
    z = x[:, 2]
    front = z > 1e-3
    zs = np.where(front, z, 1.0)
    u = np.rint(intrinsics.fx * x[:, 0] / zs + intrinsics.cx).astype(np.int64)
    v = np.rint(intrinsics.fy * x[:, 1] / zs + intrinsics.cy).astype(np.int64)
    ok = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    d = depth[np.where(ok, v, 0), np.where(ok, u, 0)]
    with np.errstate(invalid="ignore"):
        return int(np.count_nonzero(ok & np.isfinite(d) & (d > z + margin)))
