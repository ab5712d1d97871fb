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

from dataclasses import dataclass, field, replace

import numba as nb
import numpy as np

from tracker.filter.motion_model import rodrigues_terms, rotvec_to_matrix
from tracker.geometry.camera import Intrinsics
from tracker.geometry.spd_solve import solve_spd6
from tracker.refine.normal_equations import add_huber, twist_row
from tracker.refine.region_term import RegionTerm, _scene_outline
from tracker.refine.region_term import _accumulate as _region_accumulate


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
    few_points_position: bool = False
    """A part partly hidden that matched most of its observable model points, but fewer than twice ``min_points``
    (too few to pin its rotation: on the tuning traces such refinements put the centre within 1–2 mm but turned the
    part 3–12°), is refined again with its rotation held at the start (its position only); that refinement counts
    as healthy when it still matches as many (``RefineResult.position_only``)."""
    max_points: int = 700
    """Model points used per part (evenly thinned when there are more)."""
    stop_step: float = 1e-6
    """Stop early when the update's norm (rad and m) falls below this."""
    converged_step: float = 0.0
    """End all correspondence iterations (the finer thresholds too) when an update's norm (rad and m) falls below
    this: the pose has converged (0 = never; only ``stop_step`` ends an iteration's updates)."""
    converged_rotation: float = 0.0
    """With ``converged_translation``: end all correspondence iterations (the finer thresholds too) once an update
    after the first (coarsest) correspondence iteration turns the part by less than this (rad) and moves its centre by
    less than ``converged_translation`` (m); 0 = never.
    A speed setting: on the tuning traces the updates after the first few circle at 0.01–0.1° and 0.01–0.1 mm (the
    nearest-pixel depth reads and the re-extracted outline make the cost piecewise constant) instead of vanishing."""
    converged_translation: float = 0.0
    """See ``converged_rotation`` (m)."""
    outline_per_threshold: bool = False
    """With a silhouette term whose outline comes from an outline scene: its outline is re-extracted only at the first
    update of each correspondence iteration (threshold), not at every update that moved the pose (False, the
    default): the outline's points are taken at pixel positions, so re-extracting them at every update makes the
    silhouette cost piecewise constant in the pose."""
    bilinear_m: float = 0.0
    """> 0: each model point's measured depth is read bilinearly at its sub-pixel projection (the four neighbouring
    pixels, when all are valid and span less than this, m) and its measured point lies on the model point's viewing
    ray, so that the cost changes continuously with the pose; else (or 0, the default) at the nearest pixel, which
    makes the cost piecewise constant (1 mm depth steps of the simulator and the sensors) and the updates circle
    instead of vanishing."""


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
    n_observable: int = 0
    """Model points with a valid measurement on an allowed pixel and nothing in front of them (matched or not)."""
    position_only: bool = False
    """The refinement moved the part's position only (its rotation kept: ``RefineSettings.few_points_position``)."""
    n_updates: int = 0
    """Gauss-Newton updates made."""
    last_update: tuple[float, float] = (float("nan"), float("nan"))
    """The last update's turn (rad) and move of the centre (m): how far from converged the refinement stopped."""

    @property
    def score(self) -> float:
        """Support of the pose by the depth: matched model points minus twice the free-space violations."""
        return float(self.n_valid - 2 * self.n_behind)


@nb.njit(cache=True)
def _accumulate(pts, nrm, R, t, c, depth, allowed, use_allowed, thr, occlusion, fx, fy, cx, cy, sigma0, sigma_z2,
                huber_k, behind_margin, bilinear_m=0.0):
    """One correspondence pass: the weighted normal equations ``H`` (6×6) and ``g`` (6) of the point-to-plane
    residuals (twist about ``c``), the number of valid pairs, of observable model points, the median |r|, and the
    number of model points whose measurement lies more than ``behind_margin`` behind them (free space)."""
    absr = np.empty(pts.shape[0])
    H, g, n_valid, n_obs, n_behind = _accumulate_into(absr, pts, nrm, R, t, c, depth, allowed, use_allowed, thr,
                                                      occlusion, fx, fy, cx, cy, sigma0, sigma_z2, huber_k,
                                                      behind_margin, bilinear_m)
    return H, g, n_valid, n_obs, _median_of(absr, n_valid), n_behind


@nb.njit(cache=True)
def _median_of(absr, n):
    """Median of ``absr[:n]`` (NaN when n = 0)."""
    return np.median(absr[:n]) if n > 0 else np.nan


@nb.njit(cache=True)
def _accumulate_into(absr, pts, nrm, R, t, c, depth, allowed, use_allowed, thr, occlusion, fx, fy, cx, cy, sigma0,
                     sigma_z2, huber_k, behind_margin, bilinear_m=0.0):
    """:func:`_accumulate` without the median: the valid pairs' |r| are written to ``absr[:n_valid]`` (the
    Gauss-Newton loops take their median only when they stop early and report it). Returns ``H``, ``g``,
    ``n_valid``, ``n_obs``, ``n_behind``. ``bilinear_m`` > 0: :attr:`RefineSettings.bilinear_m`
    (:func:`_bilinear_depth`)."""
    h, w = depth.shape
    H = np.zeros((6, 6))
    g = np.zeros(6)
    n_valid = 0
    n_obs = 0
    n_behind = 0
    J = np.empty(6)
    for i in range(pts.shape[0]):
        x0 = R[0, 0] * pts[i, 0] + R[0, 1] * pts[i, 1] + R[0, 2] * pts[i, 2] + t[0]
        x1 = R[1, 0] * pts[i, 0] + R[1, 1] * pts[i, 1] + R[1, 2] * pts[i, 2] + t[1]
        x2 = R[2, 0] * pts[i, 0] + R[2, 1] * pts[i, 1] + R[2, 2] * pts[i, 2] + t[2]
        if x2 <= 1e-3:
            continue
        u = int(np.floor(fx * x0 / x2 + cx + 0.5))
        v = int(np.floor(fy * x1 / x2 + cy + 0.5))
        if u < 0 or u >= w or v < 0 or v >= h:
            continue
        d = depth[v, u]
        if not (d > 0.0) or not np.isfinite(d):
            continue
        qu, qv = float(u), float(v)
        if bilinear_m > 0.0:
            pu, pv = fx * x0 / x2 + cx, fy * x1 / x2 + cy
            db = _bilinear_depth(depth, pu, pv, bilinear_m)
            if db > 0.0:
                d, qu, qv = db, pu, pv
        if d > x2 + behind_margin:
            n_behind += 1
        if use_allowed and not allowed[v, u]:
            continue
        if d < x2 - occlusion:
            continue  # something in front of the model point
        n_obs += 1
        q0 = (qu - cx) / fx * d
        q1 = (qv - cy) / fy * d
        e0, e1, e2 = x0 - q0, x1 - q1, x2 - d
        if e0 * e0 + e1 * e1 + e2 * e2 >= thr * thr:
            continue
        m0 = R[0, 0] * nrm[i, 0] + R[0, 1] * nrm[i, 1] + R[0, 2] * nrm[i, 2]
        m1 = R[1, 0] * nrm[i, 0] + R[1, 1] * nrm[i, 1] + R[1, 2] * nrm[i, 2]
        m2 = R[2, 0] * nrm[i, 0] + R[2, 1] * nrm[i, 1] + R[2, 2] * nrm[i, 2]
        r = m0 * e0 + m1 * e1 + m2 * e2
        twist_row(J, x0, x1, x2, c, m0, m1, m2)
        add_huber(H, g, J, r, sigma0 + sigma_z2 * x2 * x2, huber_k, 1.0)
        absr[n_valid] = abs(r)
        n_valid += 1
    for a in range(6):
        for b in range(a):
            H[a, b] = H[b, a]
    return H, g, n_valid, n_obs, n_behind


@nb.njit(cache=True, inline="always")
def _bilinear_depth(depth, pu, pv, max_span):
    """Depth (m) at the sub-pixel position ``(pu, pv)`` (pixel centres at integers), interpolated between its four
    neighbouring pixels; 0 when one of them is outside the image or has no depth, or when they span ``max_span`` m
    or more (an edge: the caller keeps the nearest pixel's)."""
    h, w = depth.shape
    i0 = int(np.floor(pu))
    j0 = int(np.floor(pv))
    if i0 < 0 or j0 < 0 or i0 + 1 >= w or j0 + 1 >= h:
        return 0.0
    d00, d01 = depth[j0, i0], depth[j0, i0 + 1]
    d10, d11 = depth[j0 + 1, i0], depth[j0 + 1, i0 + 1]
    if not (d00 > 0.0 and d01 > 0.0 and d10 > 0.0 and d11 > 0.0):
        return 0.0
    if not (np.isfinite(d00) and np.isfinite(d01) and np.isfinite(d10) and np.isfinite(d11)):
        return 0.0
    lo = min(min(d00, d01), min(d10, d11))
    hi = max(max(d00, d01), max(d10, d11))
    if hi - lo >= max_span:
        return 0.0
    a = pu - i0
    b = pv - j0
    return (1.0 - b) * ((1.0 - a) * d00 + a * d01) + b * ((1.0 - a) * d10 + a * d11)


@nb.njit(cache=True, inline="always")
def _note_update(stats, xi, max_rot, max_trans):
    """Count one update in ``stats[0]`` and keep its turn ``‖ω‖`` (rad) and move ``‖v‖`` (m) in ``stats[1:]``;
    returns whether it turned by less than ``max_rot`` and moved by less than ``max_trans``."""
    stats[0] += 1.0
    stats[1] = np.sqrt(xi[0] * xi[0] + xi[1] * xi[1] + xi[2] * xi[2])
    stats[2] = np.sqrt(xi[3] * xi[3] + xi[4] * xi[4] + xi[5] * xi[5])
    return stats[1] < max_rot and stats[2] < max_trans


@nb.njit(cache=True)
def _gauss_newton(pts, nrm, R, t, center, depth, allowed, use_allowed, thresholds, updates, occlusion, fx, fy, cx, cy,
                  sigma0, sigma_z2, huber_k, behind, lambda_rot, lambda_trans, min_points, stop_step,
                  converged_step, converged_rot, converged_trans, bilinear_m, stats):
    """The correspondence iterations of :func:`refine_pose` (coarse to fine thresholds, ``updates`` Gauss-Newton
    steps each, the inner loop ends early when the step's norm is below ``stop_step``, all of them when it is below
    ``converged_step`` or, after the first threshold, turns by less than ``converged_rot`` (rad) and moves the centre
    by less than ``converged_trans`` (m), when that is > 0; ``bilinear_m``: :attr:`RefineSettings.bilinear_m`).
    ``stats`` (3,): the number of updates made is added to ``stats[0]``, the last update's turn (rad) and move (m)
    written to ``stats[1:]``. Updates ``R``, ``t`` in place; returns (status: 0 done, 1 too few valid pairs, 2
    singular system; the last pass's ``H``, ``n_valid``, ``n_obs``, and its median |r| when the status is 1 or 2 —
    NaN when done: the caller measures the final pose)."""
    c = np.empty(3)
    H = np.zeros((6, 6))
    n_valid, n_obs, med = 0, 0, np.nan
    absr = np.empty(pts.shape[0])
    ti = -1  # index of the correspondence iteration (threshold)
    for thr in thresholds:
        ti += 1
        for _ in range(updates):
            for a in range(3):
                c[a] = R[a, 0] * center[0] + R[a, 1] * center[1] + R[a, 2] * center[2] + t[a]
            H, g, n_valid, n_obs, _nb = _accumulate_into(absr, pts, nrm, R, t, c, depth, allowed, use_allowed, thr,
                                                         occlusion, fx, fy, cx, cy, sigma0, sigma_z2, huber_k, behind,
                                                         bilinear_m)
            med = np.nan  # taken below only when the loop stops here (the caller measures the final pose again)
            if n_valid < min_points:
                return 1, H, n_valid, n_obs, _median_of(absr, n_valid)
            A = H.copy()
            for a in range(3):
                A[a, a] += lambda_rot
                A[a + 3, a + 3] += lambda_trans
            xi, ok = solve_spd6(A, -g)
            if not ok:
                return 2, H, n_valid, n_obs, _median_of(absr, n_valid)
            # rotation about the part's centre c by exp(ω) (Rodrigues), then the translation v
            w0, w1, w2 = xi[0], xi[1], xi[2]
            theta = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
            Rw = np.eye(3)
            if theta >= 1e-12:
                k0, k1, k2 = w0 / theta, w1 / theta, w2 / theta
                K = np.array([[0.0, -k2, k1], [k2, 0.0, -k0], [-k1, k0, 0.0]])
                Rw = Rw + np.sin(theta) * K + (1.0 - np.cos(theta)) * (K @ K)
            d = t - c
            t[:] = c + Rw @ d + xi[3:]
            R[:, :] = Rw @ R
            step = np.sqrt(np.sum(xi * xi))
            small = _note_update(stats, xi, converged_rot, converged_trans)
            if step < converged_step:
                return 0, H, n_valid, n_obs, med
            if converged_rot > 0.0 and ti > 0 and small:
                return 0, H, n_valid, n_obs, med
            if step < stop_step:
                break
    return 0, H, n_valid, n_obs, med


@nb.njit(cache=True)
def _gauss_newton_region(pts, nrm, R, t, center, depth, allowed, use_allowed, thresholds, updates, occlusion, fx, fy,
                         cx, cy, sigma0, sigma_z2, huber_k, behind, lambda_rot, lambda_trans, min_points, stop_step,
                         converged_step, converged_rot, converged_trans, bilinear_m, stats, outline_once, rpts, rR,
                         rt, sd, gu, gv, su0, sv0, fdepth,
                         inset, r_occ, r_agree, r_max_px, r_sigma, r_huber, r_weight, ogu, ogv, r_min_cos, r_lines,
                         kinds, Rs, ts, centers, halves, verts, faces, voff, foff, obj, rect, r_max_points):
    """:func:`_gauss_newton_with_region` in numba for a silhouette term whose outline comes from an
    :class:`~tracker.refine.region_term.OutlineScene` (its arrays, then the term's: contour points ``rpts`` extracted
    at ``(rR, rt)``, the blob's signed distance ``sd``, ``gu``, ``gv`` with crop origin ``(su0, sv0)``, the depth
    ``fdepth`` that tells what hides the outline, and the settings). The same steps as the Python loop: the outline
    is re-extracted whenever the pose differs from the one its points came from (with ``outline_once``, only at a
    threshold's first update: :attr:`RefineSettings.outline_per_threshold`; kept when fewer than 8 points; for a
    box :func:`~tracker.refine.region_term._scene_outline` ray-casts only near its projected outline, same points),
    the update solves ``(H + H_r + Λ) ξ = −(g + g_r)`` and turns by Rodrigues' formula of
    :func:`~tracker.filter.motion_model.rotvec_to_matrix`; the same early ends (``converged_rot`` / ``converged_trans``
    as in :func:`_gauss_newton`). Updates ``R``, ``t`` in place; same return values as
    :func:`_gauss_newton`."""
    c = np.empty(3)
    H = np.zeros((6, 6))
    n_valid, n_obs, med = 0, 0, np.nan
    absr = np.empty(pts.shape[0])
    pose_R = rR.copy()
    pose_t = rt.copy()
    cur = rpts
    Rw = np.empty((3, 3))
    K = np.empty((3, 3))
    ti = -1  # index of the correspondence iteration (threshold)
    for thr in thresholds:
        ti += 1
        for ui in range(updates):
            for a in range(3):
                c[a] = R[a, 0] * center[0] + R[a, 1] * center[1] + R[a, 2] * center[2] + t[a]
            H, g, n_valid, n_obs, _nb = _accumulate_into(absr, pts, nrm, R, t, c, depth, allowed, use_allowed, thr,
                                                         occlusion, fx, fy, cx, cy, sigma0, sigma_z2, huber_k, behind,
                                                         bilinear_m)
            med = np.nan  # taken below only when the loop stops here (the caller measures the final pose again)
            if n_valid < min_points:
                return 1, H, n_valid, n_obs, _median_of(absr, n_valid)
            same = True
            for a in range(3):
                if t[a] != pose_t[a]:
                    same = False
                for b in range(3):
                    if R[a, b] != pose_R[a, b]:
                        same = False
            if not same and (ui == 0 or not outline_once):
                fresh = _scene_outline(kinds, Rs, ts, centers, halves, verts, faces, voff, foff, obj, R, t, rect,
                                       fx, fy, cx, cy, r_max_points)
                pose_R[:, :] = R
                pose_t[:] = t
                if fresh.shape[0] >= 8:
                    cur = fresh
            Hr, gr, _nr = _region_accumulate(cur, R, t, c, sd, gu, gv, su0, sv0, fdepth, fx, fy, cx, cy, inset,
                                             r_occ, r_agree, r_max_px, r_sigma, r_huber, r_weight, ogu, ogv,
                                             r_min_cos, r_lines)
            A = H + Hr
            for a in range(3):
                A[a, a] += lambda_rot
                A[a + 3, a + 3] += lambda_trans
            xi, ok = solve_spd6(A, -(g + gr))
            if not ok:
                return 2, H, n_valid, n_obs, _median_of(absr, n_valid)
            fa, fb = rodrigues_terms(xi[0], xi[1], xi[2], K)
            for a in range(3):
                for b in range(3):
                    kk = K[a, 0] * K[0, b] + K[a, 1] * K[1, b] + K[a, 2] * K[2, b]
                    Rw[a, b] = (1.0 if a == b else 0.0) + fa * K[a, b] + fb * kk
            d0, d1, d2 = t[0] - c[0], t[1] - c[1], t[2] - c[2]
            for a in range(3):
                t[a] = c[a] + (Rw[a, 0] * d0 + Rw[a, 1] * d1 + Rw[a, 2] * d2) + xi[3 + a]
            Rn = Rw @ R
            R[:, :] = Rn
            step = np.sqrt(np.sum(xi * xi))
            small = _note_update(stats, xi, converged_rot, converged_trans)
            if step < converged_step:
                return 0, H, n_valid, n_obs, med
            if converged_rot > 0.0 and ti > 0 and small:
                return 0, H, n_valid, n_obs, med
            if step < stop_step:
                break
    return 0, H, n_valid, n_obs, med


def _gauss_newton_with_region(pts, nrm, R, t, center, dep, mask, use_mask, cfg: RefineSettings, behind: float,
                              intrinsics: Intrinsics, region: RegionTerm, stats: np.ndarray):
    """:func:`_gauss_newton` with the silhouette term's normal equations added to every update (a Python loop: the
    term re-renders the part's outline at each pose). Updates ``R``, ``t`` and ``stats`` in place; same return
    values."""
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    prior = np.diag([cfg.lambda_rot] * 3 + [cfg.lambda_trans] * 3)
    info, n_valid, n_obs, med = np.zeros((6, 6)), 0, 0, float("nan")
    for ti, thr in enumerate(cfg.thresholds):
        for _ in range(cfg.updates_per_iteration):
            c = R @ center + t
            info, g, n_valid, n_obs, med, _ = _accumulate(pts, nrm, R, t, c, dep, mask, use_mask, float(thr),
                                                          cfg.occlusion_m, fx, fy, cx, cy, cfg.sigma0, cfg.sigma_z2,
                                                          cfg.huber_k, behind, float(cfg.bilinear_m))
            if n_valid < cfg.min_points:
                return 1, info, n_valid, n_obs, med
            Hr, gr, _ = region.normal_equations(R, t, c, dep, intrinsics)
            xi = -np.linalg.solve(info + Hr + prior, g + gr)
            Rw = rotvec_to_matrix(xi[:3])[0]
            t[:] = c + Rw @ (t - c) + xi[3:]
            R[:] = Rw @ R
            step = np.linalg.norm(xi)
            small = _note_update(stats, xi, cfg.converged_rotation, cfg.converged_translation)
            if step < cfg.converged_step:
                return 0, info, n_valid, n_obs, med
            if cfg.converged_rotation > 0.0 and ti > 0 and small:
                return 0, info, n_valid, n_obs, med
            if step < cfg.stop_step:
                break
    return 0, info, n_valid, n_obs, med


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
    region: RegionTerm | None = None,
) -> RefineResult:
    """Refine the pose ``(R, t)`` of a part whose visible model points are ``points`` with ``normals`` (body frame,
    (M, 3) each) against ``depth`` (H×W float metres, NaN or 0 = none). ``center``: the body-frame point the
    rotation update turns about. ``allowed``: optional H×W bool mask of pixels the part may claim (its colour blob;
    pixels of hands or other parts left out). ``region``: optional silhouette term
    (:mod:`tracker.refine.region_term`) added to every update's normal equations."""
    cfg = settings or RefineSettings()
    R0, t0 = R, t
    R = np.asarray(R, np.float64).copy()
    t = np.asarray(t, np.float64).copy()
    pts = np.asarray(points, np.float64)
    nrm = np.asarray(normals, np.float64)
    if pts.shape[0] > cfg.max_points:
        sel = np.linspace(0, pts.shape[0] - 1, cfg.max_points).round().astype(np.int64)
        pts, nrm = pts[sel], nrm[sel]
    m_total = pts.shape[0]
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    info = np.zeros((6, 6))
    n_valid, n_observable, med = 0, 0, float("nan")
    if m_total < cfg.min_points:
        return RefineResult(R, t, False, m_total, 0, 0.0, med, info, "too few visible model points")
    mask = np.zeros((1, 1), np.bool_) if allowed is None else np.ascontiguousarray(allowed, np.bool_)
    dep = np.ascontiguousarray(depth, np.float32)
    center = np.asarray(center, np.float64)
    behind = cfg.thresholds[-1] * 2.0
    stats = np.zeros(3)
    stats[1:] = np.nan

    if region is None:
        status, info, n_valid, n_observable, med = _gauss_newton(
            pts, nrm, R, t, center, dep, mask, allowed is not None, np.asarray(cfg.thresholds, np.float64),
            int(cfg.updates_per_iteration), cfg.occlusion_m, fx, fy, cx, cy, cfg.sigma0, cfg.sigma_z2, cfg.huber_k,
            behind, cfg.lambda_rot, cfg.lambda_trans, int(cfg.min_points), cfg.stop_step, float(cfg.converged_step),
            float(cfg.converged_rotation), float(cfg.converged_translation), float(cfg.bilinear_m), stats)
    elif region.scene is not None:
        sc, f, rs = region.scene, region.sdf, region.settings
        if not (region.pose is not None and region.outline_at is not None):
            raise ValueError("a silhouette term with an outline scene needs its start pose and outline_at")
        status, info, n_valid, n_observable, med = _gauss_newton_region(
            pts, nrm, R, t, center, dep, mask, allowed is not None, np.asarray(cfg.thresholds, np.float64),
            int(cfg.updates_per_iteration), cfg.occlusion_m, fx, fy, cx, cy, cfg.sigma0, cfg.sigma_z2, cfg.huber_k,
            behind, cfg.lambda_rot, cfg.lambda_trans, int(cfg.min_points), cfg.stop_step, float(cfg.converged_step),
            float(cfg.converged_rotation), float(cfg.converged_translation), float(cfg.bilinear_m), stats,
            bool(cfg.outline_per_threshold), np.ascontiguousarray(region.points, np.float64),
            np.ascontiguousarray(region.pose[0], np.float64),
            np.ascontiguousarray(region.pose[1], np.float64), f.d, f.gu, f.gv, float(f.u0), float(f.v0),
            dep if region.frame_depth is None else region.frame_depth, float(region.inset), rs.occlusion_m,
            rs.depth_agree_m, rs.max_px, rs.sigma_px, rs.huber_k, rs.weight, *region.normal_arrays(), sc.kinds,
            sc.Rs, sc.ts, sc.centers,
            sc.halves, sc.verts, sc.faces, sc.voff, sc.foff, sc.obj, sc.rect, sc.max_points)
    else:
        status, info, n_valid, n_observable, med = _gauss_newton_with_region(
            pts, nrm, R, t, center, dep, mask, allowed is not None, cfg, behind, intrinsics, region, stats)
    n_upd, last = int(stats[0]), (float(stats[1]), float(stats[2]))
    if status == 1:
        return RefineResult(R, t, False, m_total, n_valid, n_valid / m_total, med, info,
                            f"only {n_valid} valid depth pairs", n_updates=n_upd, last_update=last)
    if status == 2:
        return RefineResult(R, t, False, m_total, n_valid, n_valid / m_total, med, info, "singular system",
                            n_updates=n_upd, last_update=last)
    info, _, n_valid, n_observable, med, n_behind = _accumulate(  # support of the final pose
        pts, nrm, R, t, R @ center + t, dep, mask, allowed is not None, float(cfg.thresholds[-1]), cfg.occlusion_m,
        fx, fy, cx, cy, cfg.sigma0, cfg.sigma_z2, cfg.huber_k, behind, float(cfg.bilinear_m))
    frac = n_valid / m_total
    # supported: enough of the model matched, or (partly hidden by a hand or another part) most of what can be seen
    most_seen = n_valid >= cfg.min_observed_fraction * max(n_observable, 1)
    healthy = frac >= cfg.min_valid_fraction or (n_valid >= 2 * cfg.min_points and most_seen)
    res = RefineResult(R, t, healthy, m_total, n_valid, frac, med, info,
                       "" if healthy else f"only {frac:.0%} of the visible model points matched the depth", n_behind,
                       n_observable, n_updates=n_upd, last_update=last)
    if not healthy and cfg.few_points_position and most_seen:
        return _position_only(depth, intrinsics, points, normals, R0, t0, center, cfg, allowed, region, res)
    return res


def _position_only(depth, intrinsics, points, normals, R0, t0, center, cfg: RefineSettings, allowed, region,
                   full: RefineResult) -> RefineResult:
    """``few_points_position``: the refinement of a partly hidden part from ``(R0, t0)`` with its rotation held
    (a rotation prior a million times the usual), healthy when it matches at least ``min_points`` and
    ``min_observed_fraction`` of its observable model points; else ``full``, the unhealthy full refinement."""
    held = replace(cfg, lambda_rot=cfg.lambda_rot * 1e6, few_points_position=False)  # (no second position-only pass)
    res = refine_pose(depth, intrinsics, points, normals, R0, t0, center, held, allowed, region)
    if res.n_valid < cfg.min_points or res.n_valid < cfg.min_observed_fraction * max(res.n_observable, 1):
        return full
    R0 = np.asarray(R0, np.float64)
    res.t = res.t + (res.R - R0) @ np.asarray(center, np.float64)  # exactly the start rotation about the same centre
    res.R = R0.copy()
    res.healthy, res.position_only = True, True
    res.reason = f"position only: {res.n_valid} of {res.n_observable} observable model points matched"
    return res

