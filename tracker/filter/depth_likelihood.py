"""Depth observation model with per-pixel occlusion (spec sections 4.8–4.10), numpy reference + numba kernels.

Per pixel with observed depth z and rendered depth d (metres, camera-frame z):

* σ(z) = σ_model + σ_factor·z² (reference default; one σ for both cases).
* visible  p_v(z|d) = (1 − β) N(z | d, σ) + β/m                                               (4.33)
* occluded p_o(z|d) = (1 − β) λ e^(−λz + ½λ²σ²) · ½[1 + erf((d − z + λσ²)/(√2σ))] / (1 − e^(−λd)) + β/m
  (stable form of 4.34); no object on the pixel: p_o(z|∞) = β/m + (1 − β) λ e^(−λz + ½λ²σ²).
* with predicted occlusion probability ô the pixel likelihood is ℓ = p_v(1 − ô) + p_o ô, and each covered
  pixel contributes log(ℓ / p_o(z|∞)) to a particle's log-likelihood (relative to "no object here"); uncovered
  pixels contribute 0. Occlusion posterior o' = p_o ô / ℓ (4.45); uncovered pixels keep ô.
* occlusion prediction over Δt seconds from the stored posterior o with rate parameters p(1|0), p(1|1):
  c = p(1|1) − p(1|0), ô = 1 − [c^Δt (1 − o) + (1 − p(1|1)) (c^Δt − 1)/(c − 1)].

Invalid depth (NaN, ≤ 0 or ≥ m) never enters: such pixels are not in the evaluated pixel list.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

_SQRT2 = math.sqrt(2.0)
_SQRT2PI = math.sqrt(2.0 * math.pi)


@dataclass(frozen=True)
class LikelihoodParams:
    """Observation-model constants (see :class:`tracker.filter.tracker_config.TrackerConfig`)."""

    tail_weight: float = 0.01
    sigma_model: float = 0.003
    sigma_factor: float = 0.00142478
    occluder_rate: float = math.log(2.0)
    max_depth: float = 6.0

    @staticmethod
    def from_config(cfg) -> LikelihoodParams:
        return LikelihoodParams(cfg.tail_weight, cfg.sigma_model, cfg.sigma_factor, cfg.occluder_rate, cfg.max_depth)


def depth_sigma(z: np.ndarray, prm: LikelihoodParams) -> np.ndarray:
    """σ(z) = σ_model + σ_factor·z², metres."""
    z = np.asarray(z, np.float64)
    return prm.sigma_model + prm.sigma_factor * z * z


def visible_likelihood(z, d, prm: LikelihoodParams) -> np.ndarray:
    """p_v(z | d) of (4.33) with σ(z)."""
    z = np.asarray(z, np.float64)
    d = np.asarray(d, np.float64)
    s = depth_sigma(z, prm)
    gauss = np.exp(-0.5 * ((z - d) / s) ** 2) / (_SQRT2PI * s)
    gauss = np.where(np.isfinite(d), gauss, 0.0)
    return (1.0 - prm.tail_weight) * gauss + prm.tail_weight / prm.max_depth


def occluded_likelihood(z, d, prm: LikelihoodParams) -> np.ndarray:
    """p_o(z | d) of (4.34) in the numerically stable form; ``d = inf`` gives p_o(z | ∞)."""
    from scipy.special import erf

    z = np.asarray(z, np.float64)
    d = np.asarray(d, np.float64)
    s = depth_sigma(z, prm)
    lam = prm.occluder_rate
    e = (1.0 - prm.tail_weight) * lam * np.exp(-lam * z + 0.5 * lam * lam * s * s)
    with np.errstate(invalid="ignore", over="ignore"):
        frac = 0.5 * (1.0 + erf((d - z + lam * s * s) / (_SQRT2 * s))) / (1.0 - np.exp(-lam * d))
    frac = np.where(np.isfinite(d), frac, 1.0)
    return e * frac + prm.tail_weight / prm.max_depth


def predict_occlusion(o: np.ndarray, dt: np.ndarray | float, p_occ_vis: float, p_occ_occ: float) -> np.ndarray:
    """Predicted occlusion probability ô after Δt seconds (rate form of spec 4.8; Δt = 1 gives one step)."""
    o = np.asarray(o, np.float64)
    c = p_occ_occ - p_occ_vis
    dt = np.asarray(dt, np.float64)
    if abs(c - 1.0) < 1e-12:
        return o.copy()
    if c <= 0.0:  # the rate form needs c > 0; fall back to one step per call
        return p_occ_occ * o + p_occ_vis * (1.0 - o)
    cd = np.power(c, dt)
    return 1.0 - (cd * (1.0 - o) + (1.0 - p_occ_occ) * (cd - 1.0) / (c - 1.0))


def occlusion_affine(dt: np.ndarray, p_occ_vis: float, p_occ_occ: float) -> tuple[np.ndarray, np.ndarray] | None:
    """The prediction of :func:`predict_occlusion` over Δt per pixel ``dt`` (P,) as the affine map ô = a·o + b,
    ``a``, ``b`` float32 (P,); None when it is the identity (c = 1)."""
    c = p_occ_occ - p_occ_vis
    dt = np.asarray(dt, np.float64)
    if abs(c - 1.0) < 1e-12:
        return None
    if c <= 0.0:
        a = np.full(dt.shape, p_occ_occ - p_occ_vis)
        b = np.full(dt.shape, p_occ_vis)
    else:  # ô = 1 − [c^Δt (1 − o) + (1 − p11)(c^Δt − 1)/(c − 1)] = c^Δt o + (1 − c^Δt − (1 − p11)(c^Δt − 1)/(c − 1))
        cd = np.power(c, dt)
        a = cd
        b = 1.0 - cd - (1.0 - p_occ_occ) * (cd - 1.0) / (c - 1.0)
    return a.astype(np.float32), b.astype(np.float32)


def predict_occlusion_rows(o: np.ndarray, dt: np.ndarray, p_occ_vis: float, p_occ_occ: float) -> np.ndarray:
    """:func:`predict_occlusion` for pixel-major float32 rows ``o`` (P, N) with one Δt per pixel ``dt`` (P,);
    the affine map is computed once per pixel. Returns float32 (P, N)."""
    o = np.asarray(o, np.float32)
    ab = occlusion_affine(dt, p_occ_vis, p_occ_occ)
    if ab is None:
        return o.copy()
    a, b = ab
    return (o * a[:, None] + b[:, None]).astype(np.float32, copy=False)


@nb.njit(cache=True)
def predicted_occlusion(occ, pix, a, b, floor):
    """ô (N, P) float32, particle-major, of the stored pixel-major posteriors ``occ`` (P_grid, N) at the grid pixels
    ``pix`` (P,): ``max(a·o + b, floor)`` per pixel (:func:`occlusion_affine`; ``a`` None-equivalent: pass a = 1,
    b = 0), the float32 arithmetic of :func:`predict_occlusion_rows` followed by ``np.maximum`` with ``floor`` (P,)
    (e.g. a hand's occluder prior; zeros for none)."""
    n = occ.shape[1]
    p = pix.shape[0]
    out = np.empty((n, p), np.float32)
    for i in range(p):
        row = pix[i]
        ai = a[i]
        bi = b[i]
        fl = floor[i]
        for j in range(n):
            v = occ[row, j] * ai + bi
            out[j, i] = v if v >= fl or v != v else fl
    return out


def pixel_constants(z: np.ndarray, prm: LikelihoodParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel constants of the kernels: σ(z), e(z) = (1−β)λe^(−λz+½λ²σ²) and log p_o(z|∞)."""
    s = depth_sigma(z, prm)
    lam = prm.occluder_rate
    e = (1.0 - prm.tail_weight) * lam * np.exp(-lam * z + 0.5 * lam * lam * s * s)
    log_po_inf = np.log(e + prm.tail_weight / prm.max_depth)
    return s, e, log_po_inf


@nb.njit(cache=True, inline="always")
def _pixel_terms(d, z, s, e, o_hat, beta, lam, tail, use_occ):
    """Returns (ℓ, p_o·ô) of one covered pixel. The transcendental calls are skipped where their value is exact
    without them (same results bit for bit): ``exp(−r²/2)`` is 0 in float64 for r² ≥ 1500 (below e^−745),
    ``erf(x)`` is ±1 for |x| ≥ 6 (erfc(6) ≈ 2e−17 is below half an ulp of 1), and at ``erf = −1`` the occluded
    term is exactly the tail."""
    r = (z - d) / s
    r2 = r * r
    if r2 < 1500.0:
        pv = (1.0 - beta) * math.exp(-0.5 * r2) / (2.5066282746310002 * s) + tail
    else:
        pv = tail
    if not use_occ:
        return pv, 0.0
    x = (d - z + lam * s * s) / (1.4142135623730951 * s)
    if x <= -6.0:
        po = tail
    else:
        den = 1.0 - math.exp(-lam * d)
        if den < 1e-12:
            den = 1e-12
        po = e * 0.5 * (1.0 + (1.0 if x >= 6.0 else math.erf(x))) / den + tail
    return pv * (1.0 - o_hat) + po * o_hat, po * o_hat


@nb.njit(cache=True)
def update_log_likelihood(D, loc, subset, z, s, e, log_po_inf, o_hat, anc, C, Q, F, ell, beta, lam, tail, use_occ,
                          dirty, alpha, cmask, cvalid, occ_cap=0.0, fresh=False):
    """Recompute the contributions of the dirty ``subset`` pixels for every particle and update ``ell`` in place.

    * ``D`` (N, M) rendered depth columns, ``loc`` (K, P) column of part k at pixel i or −1 (part k cannot cover
      pixel i); ``inf`` = not covered; the pixel depth is the z-buffer minimum over the parts.
    * ``z``, ``s``, ``e``, ``log_po_inf`` (P,) per-pixel observation constants (:func:`pixel_constants`).
    * ``o_hat`` (N, P) predicted occlusion probabilities of the particles at the start of the frame and ``anc``
      (N,) each current particle's ancestor among them (resampling permutes ``anc`` instead of copying ``o_hat``);
      ``C`` (N, P) cached contributions; ``ell`` (N,).
    * ``Q`` (N, P) float32 receives the occlusion posterior p_o ô / ℓ (4.45) of covered pixels (−1 = uncovered),
      ``F`` (N, P) int8 the front-most part (−1 = none); see :func:`finish_occlusion`.
    * ``dirty`` (N, P) uint8: only pixels flagged 1 (a rendered depth changed) are recomputed; flags are cleared.
    * ``alpha``: exponent of every pixel's likelihood ratio (1 = independent pixels, as in the spec).
    * ``cmask`` (K, P) uint8 colour masks, ``cvalid`` (K,) uint8: where part o is front-most, has a valid colour
      mask and the pixel is outside it, the part cannot be the visible surface: the pixel is treated as occluded
      (ô = 1) and its contribution is capped at 0 (only the penalty of a part in front of the observed surface
      remains). All-zero ``cvalid`` = depth only (the spec).
    * ``occ_cap`` > 0: likewise cap at 0 the contribution of every pixel where the rendered part lies more than
      ``occ_cap`` σ behind the observed depth (occlusion is then no evidence for a pose; 0 = the spec).
    * ``fresh``: ``C``, ``Q``, ``F`` hold nothing yet (a frame's first call, over all its pixels): every ``subset``
      pixel is written, a clean one as uncovered (``C`` 0, ``Q`` −1, ``F`` −1), a dirty one as if its cached
      contribution were 0 — the values of a call on arrays filled with those first, without the fills.

    A pixel's contribution and posterior depend only on its z-buffer depth, front part and ô: when these equal the
    ones last computed at the pixel in this call (a particle that is a copy of the one before, as a resampling
    leaves them), that result is taken again (the same values) instead of evaluating the kernels.
    """
    n = D.shape[0]
    k = loc.shape[0]
    m = subset.shape[0]
    # per subset pixel, the parts that can cover it and their depth columns (in part order)
    n_cover = np.zeros(m, np.int64)
    cover_part = np.empty((m, k), np.int64)
    cover_col = np.empty((m, k), np.int64)
    for ii in range(m):
        i = subset[ii]
        for o in range(k):
            col = loc[o, i]
            if col >= 0:
                cover_part[ii, n_cover[ii]] = o
                cover_col[ii, n_cover[ii]] = col
                n_cover[ii] += 1
    # per subset pixel, the inputs and results of its last evaluation in this call
    memo_ok = np.zeros(m, np.bool_)
    memo_d = np.empty(m)
    memo_front = np.empty(m, np.int64)
    memo_oh = np.empty(m, o_hat.dtype)
    memo_c = np.empty(m)
    memo_q = np.empty(m, Q.dtype)
    todo = np.empty(m, np.int64)  # the particle's dirty subset positions, in subset order
    for j in range(n):
        cnt = 0
        if fresh:
            for ii in range(m):
                i = subset[ii]
                if dirty[j, i] == 0:
                    C[j, i] = 0.0
                    Q[j, i] = -1.0
                    F[j, i] = -1
                else:
                    todo[cnt] = ii
                    cnt += 1
        else:
            # branch-free compaction of the dirty positions (15-35 % of a pass's subset, in no predictable pattern)
            for ii in range(m):
                todo[cnt] = ii
                cnt += dirty[j, subset[ii]] != 0
        acc = 0.0
        for tt in range(cnt):
            ii = todo[tt]
            i = subset[ii]
            dirty[j, i] = 0
            d = np.inf
            front = -1
            for q in range(n_cover[ii]):
                dq = D[j, cover_col[ii, q]]
                if dq < d:
                    d = dq
                    front = cover_part[ii, q]
            F[j, i] = front
            if d == np.inf:
                c = 0.0
                Q[j, i] = -1.0
            else:
                oh_in = o_hat[anc[j], i]
                if memo_ok[ii] and memo_d[ii] == d and memo_front[ii] == front and memo_oh[ii] == oh_in:
                    c = memo_c[ii]
                    Q[j, i] = memo_q[ii]
                else:
                    oh = oh_in
                    forced = cvalid[front] and not cmask[front, i]
                    if forced:
                        oh = 1.0
                    lik, num = _pixel_terms(d, z[i], s[i], e[i], oh, beta, lam, tail, True if oh == 1.0 else use_occ)
                    c = alpha * (math.log(lik) - log_po_inf[i])
                    if c > 0.0 and (forced or (occ_cap > 0.0 and d - z[i] > occ_cap * s[i])):
                        # a pixel that cannot show the part carries no evidence for it; without this cap the
                        # truncated occluder density 1/(1 − e^(−λd)) rewards parts for hiding just behind a hand
                        c = 0.0
                    Q[j, i] = num / lik if use_occ else oh_in
                    memo_ok[ii] = True
                    memo_d[ii] = d
                    memo_front[ii] = front
                    memo_oh[ii] = oh_in
                    memo_c[ii] = c
                    memo_q[ii] = Q[j, i]
            acc += c - (0.0 if fresh else C[j, i])
            C[j, i] = c
        ell[j] += acc


def finish_occlusion(Q, F, o_hat, anc, k):
    """Occlusion posterior (N, P) from the cached per-pixel values of :func:`update_log_likelihood` (ô where no
    part covers the pixel) and each part's visible fraction (N, K): mean of 1 − o' over the pixels where the part
    is front-most (0 when it is front-most nowhere). (:func:`finish_occlusion_into` into a new pixel-major array.)"""
    n, p = Q.shape
    post = np.empty((p, n), np.float32)
    vis = finish_occlusion_into(Q, F, o_hat, anc, k, post, np.arange(p, dtype=np.int64))
    return post.T, vis


@nb.njit(cache=True)
def finish_occlusion_into(Q, F, o_hat, anc, k, occ, rows):
    """:func:`finish_occlusion` written straight into the pixel-major store ``occ`` (P_grid, N) float32: the
    posterior of particle j at evaluated pixel i goes to ``occ[rows[i], j]`` (the tracker's stored posteriors at the
    evaluated grid pixels ``rows``, without the (N, P) array and its transposed scatter). Returns the visible
    fractions (N, K)."""
    n, p = Q.shape
    vis = np.zeros((n, k))
    cnt = np.zeros((n, k))
    for j in range(n):
        a = anc[j]
        for i in range(p):
            q = Q[j, i]
            if q < 0.0:
                occ[rows[i], j] = o_hat[a, i]
            else:
                occ[rows[i], j] = q
                f = F[j, i]
                cnt[j, f] += 1.0
                vis[j, f] += 1.0 - q
        for o in range(k):
            vis[j, o] = vis[j, o] / cnt[j, o] if cnt[j, o] > 0 else 0.0
    return vis
