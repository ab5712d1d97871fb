"""The thesis's particle filter for one hand (hand-tracking spec §4, Algorithm 10).

State x = (x, y, w, h, x', y') in image pixels (centre, size, velocity in px/frame). Per step: for every particle
the adaptive transition of eq. 6.11 (position eq. 6.14, size eq. 6.19, velocity eq. 6.13, built from the forward
flows, their motion clusters and the particle's box at k−1) or, if it passes the section-6 test, the deterministic
transition; weights ×= p(y_k | x_k) (eq. 6.20); normalise; systematic resampling when N_eff < N_T; MMSE estimate
(eq. 6.9). Fallbacks of §14.8 (constant components when the box holds < n_min colour pixels or no cluster pixel;
box size clamped to [4 px, image size]; weights reset if all vanish). The deterministic transition sets the state
exactly (σ_δ = 1e-6 px of eq. 6.60 is below any pixel rounding).

Statistics that depend only on a particle's rounded box at k−1 are computed once per distinct box (after
resampling many particles share one).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from tracker.hands.box_stats import box_of, observe_states, transition_stats_of_states
from tracker.hands.certainty import TAU_D, certain_state
from tracker.hands.exclusion import F0 as EXCL_F0
from tracker.hands.exclusion import KAPPA as EXCL_KAPPA
from tracker.hands.exclusion import exclusion_factors
from tracker.hands.features import HandFeatures
from tracker.hands.palm_cut import ANCHOR_INSIDE, match_anchor


@dataclass(frozen=True)
class PFParams:
    """``n_particles`` N_s (30), ``n_threshold`` N_T (None: ⌊N_s/2⌋), ``n_r`` ratio-set subsample (64), ``n_min``
    (10 px), ``tau_d`` (0.8), σ_{p,0} = σ_{s,0} = 1 px, σ_{v,fb} = 1 px/frame, â_{c,1} (0.9), â_{m,1} (0.85), the
    boundary-weight scale (80 px², eq. 6.22) and the velocity-agreement scale (7 (px/frame)², eq. 6.31) (thesis /
    spec §16; pixel quantities in the tracker's working resolution)."""

    n_particles: int = 30
    n_threshold: int | None = None
    n_r: int = 64
    n_min: int = 10
    tau_d: float = TAU_D
    sigma_p0: float = 1.0
    sigma_s0: float = 1.0
    sigma_vfb: float = 1.0
    ac_hat: float = 0.9
    am_hat: float = 0.85
    d2_scale: float = 80.0
    v2_scale: float = 7.0

    @property
    def nt(self) -> int:
        return self.n_threshold if self.n_threshold is not None else self.n_particles // 2


@nb.njit(cache=True, nogil=True)
def _gauss2(mx, my, s00, s01, s11, z0, z1):
    """A draw of N((mx, my), [[s00, s01], [s01, s11]]) from two standard normals (Cholesky of the 2×2)."""
    l00 = np.sqrt(max(s00, 1e-12))
    l10 = s01 / l00
    l11 = np.sqrt(max(s11 - l10 * l10, 1e-12))
    return mx + l00 * z0, my + l10 * z0 + l11 * z1


@nb.njit(cache=True, nogil=True)
def _propagate(parts, stats, cent, cc, n_comp, cc_area, cc_box, cc_cut, ox, oy, W, H, u3, z, n_min, tau_d,
               sp0, ss0, svfb):  # fmt: skip
    """New particles [N, 6] and the section-6 flags [N]; ``stats`` [N, 2, 9] = transition_stats per particle and α,
    ``cent`` [2, N_c, 2] forward centroids; ``u3`` [N, 3] uniforms, ``z`` [N, 3, 2] standard normals."""
    n = parts.shape[0]
    out = np.empty_like(parts)
    det = np.zeros(n, np.bool_)
    c = np.empty((2, 2))
    ratio = np.empty((2, 2))
    cert_pass = np.zeros(n, np.bool_)
    cert_state = np.zeros((n, 6))
    for i in range(n):
        x, y, w, h, vx, vy = parts[i]
        ok = stats[i, 0, 0] >= n_min
        for a in range(2):
            m = int(stats[i, a, 1])
            if m < 0:
                ok = False
                c[a, 0] = np.nan
                c[a, 1] = np.nan
            else:
                c[a, 0] = cent[a, m, 0]
                c[a, 1] = cent[a, m, 1]
            ratio[a, 0] = stats[i, a, 5]
            ratio[a, 1] = stats[i, a, 6]
        # the section-6 test depends only on (x, y, w, h) and the box statistics: a particle equal to an earlier one
        # (resampling copies particles; the deterministic transition puts many on one state) takes its result
        same = -1
        for j in range(i):
            if parts[j, 0] == x and parts[j, 1] == y and parts[j, 2] == w and parts[j, 3] == h:
                eq = True
                for a in range(2):
                    for q in range(9):
                        sj = stats[j, a, q]
                        si = stats[i, a, q]
                        if not (sj == si or (sj != sj and si != si)):
                            eq = False
                if eq:
                    same = j
                    break
        if same >= 0:
            passed = cert_pass[same]
            st = cert_state[same]
        else:
            passed, st = certain_state(x, y, w, h, c, ratio, cc, n_comp, cc_area, cc_box, cc_cut, ox, oy, tau_d)
        cert_pass[i] = passed
        cert_state[i] = st
        if passed:
            out[i] = st
            det[i] = True
        elif not ok:
            out[i, 0] = x + vx + sp0 * z[i, 0, 0]
            out[i, 1] = y + vy + sp0 * z[i, 0, 1]
            out[i, 2] = w + ss0 * z[i, 1, 0]
            out[i, 3] = h + ss0 * z[i, 1, 1]
            out[i, 4] = vx + svfb * z[i, 2, 0]
            out[i, 5] = vy + svfb * z[i, 2, 1]
        else:
            # position: 0.4 constant velocity, 0.3 / 0.3 the two PMC centroids (eq. 6.14)
            u = u3[i, 0]
            if u < 0.4:
                out[i, 0] = x + vx + sp0 * z[i, 0, 0]
                out[i, 1] = y + vy + sp0 * z[i, 0, 1]
            else:
                a = 0 if u < 0.7 else 1
                out[i, 0], out[i, 1] = _gauss2(x + c[a, 0], y + c[a, 1], stats[i, a, 2], stats[i, a, 3],
                                               stats[i, a, 4], z[i, 0, 0], z[i, 0, 1])  # fmt: skip
            # size: 0.3 constant, 0.35 / 0.35 scaled by the ratio means (eq. 6.19)
            u = u3[i, 1]
            if u < 0.3:
                out[i, 2] = w + ss0 * z[i, 1, 0]
                out[i, 3] = h + ss0 * z[i, 1, 1]
            else:
                a = 0 if u < 0.65 else 1
                out[i, 2] = ratio[a, 0] * w + w * np.sqrt(stats[i, a, 7]) * z[i, 1, 0]
                out[i, 3] = ratio[a, 1] * h + h * np.sqrt(stats[i, a, 8]) * z[i, 1, 1]
            # velocity: 0.5 / 0.5 the two PMC centroids (eq. 6.13)
            a = 0 if u3[i, 2] < 0.5 else 1
            out[i, 4], out[i, 5] = _gauss2(c[a, 0], c[a, 1], stats[i, a, 2], stats[i, a, 3], stats[i, a, 4],
                                           z[i, 2, 0], z[i, 2, 1])  # fmt: skip
        out[i, 2] = min(max(out[i, 2], 4.0), W)
        out[i, 3] = min(max(out[i, 3], 4.0), H)
    return out, det


@nb.njit(cache=True, nogil=True)
def _take_anchor(new, det, parts, anc, inside):
    """The wrist cut for every particle, in place: a particle not in the section-6 mode, or whose section-6 box is
    larger than the anchor ``anc`` (inclusive box) and holds at least ``inside`` of its area, takes the anchor's
    state (:func:`~tracker.hands.palm_cut.anchor_state`, velocity from the particle's centre at k−1 in ``parts``)
    and counts as in the mode (:func:`~tracker.hands.palm_cut.holds_anchor` per particle, compiled)."""
    u0, v0, u1, v1 = anc[0], anc[1], anc[2], anc[3]
    sb = (u1 - u0 + 1) * (v1 - v0 + 1)
    for i in range(new.shape[0]):
        if det[i]:
            b0, b1, b2, b3 = box_of(new[i, 0], new[i, 1], new[i, 2], new[i, 3])
            iw = min(b2, u1) - max(b0, u0) + 1
            ih = min(b3, v1) - max(b1, v0) + 1
            sa = (b2 - b0 + 1) * (b3 - b1 + 1)
            if not (sa > sb and max(iw, 0.0) * max(ih, 0.0) >= inside * sb):
                continue
        x = 0.5 * (u0 + u1)
        y = 0.5 * (v0 + v1)
        new[i, 0] = x
        new[i, 1] = y
        new[i, 2] = u1 - u0
        new[i, 3] = v1 - v0
        new[i, 4] = x - parts[i, 0]
        new[i, 5] = y - parts[i, 1]
        det[i] = True


def observe(parts: np.ndarray, feats: HandFeatures, n_clusters: int, prm: PFParams) -> tuple[np.ndarray, np.ndarray]:
    """(p(y_k | x_k^i), a_{c,1}) of every particle; the box statistics once per distinct box (one numba call)."""
    return observe_states(np.ascontiguousarray(parts, np.float64), float(feats.roi[0]), float(feats.roi[1]),
                          feats.mcur, feats.labb[0], feats.labb[1], n_clusters, float(prm.d2_scale),
                          feats.centb[0].astype(np.float64), feats.centb[1].astype(np.float64), float(prm.ac_hat),
                          float(prm.am_hat), float(prm.v2_scale))  # fmt: skip


def box_stats_per_particle(parts: np.ndarray, feats: HandFeatures, n_clusters: int, n_r: int) -> np.ndarray:
    """transition_stats [N, 2, 9] of every particle's box at k−1 on both forward flows (once per distinct box)."""
    return transition_stats_of_states(np.ascontiguousarray(parts, np.float64), float(feats.roi[0]),
                                      float(feats.roi[1]), feats.mprev, feats.ff[0], feats.ff[1], feats.labf[0],
                                      feats.labf[1], n_clusters, n_r)  # fmt: skip


MODE_F = 0.5
"""Box F-score with the heaviest particle above which a particle belongs to the estimate's mode."""


def mode_estimate(parts: np.ndarray, w: np.ndarray) -> np.ndarray:
    """The MMSE estimate (eq. 6.9) over the particles of the dominant mode: the weighted mean of the particles whose
    box overlaps the heaviest particle's box with F-score ≥ MODE_F (product choice: when the particles split between
    two hands, the plain weighted mean lies between them, on neither)."""
    b = np.column_stack([parts[:, 0] - parts[:, 2] / 2, parts[:, 1] - parts[:, 3] / 2, parts[:, 0] + parts[:, 2] / 2,
                         parts[:, 1] + parts[:, 3] / 2])  # fmt: skip
    k = int(np.argmax(w))
    iw = np.clip(np.minimum(b[:, 2], b[k, 2]) - np.maximum(b[:, 0], b[k, 0]), 0, None)
    ih = np.clip(np.minimum(b[:, 3], b[k, 3]) - np.maximum(b[:, 1], b[k, 1]), 0, None)
    area = parts[:, 2] * parts[:, 3]
    f = 2 * iw * ih / np.maximum(area + area[k], 1e-9)
    sel = f >= MODE_F
    ws = w[sel]
    return (ws[:, None] * parts[sel]).sum(axis=0) / ws.sum()


def systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices drawn by systematic resampling (Algorithm 7 with erratum E2: cumulative sum starting at w^1)."""
    n = len(weights)
    c = np.cumsum(weights)
    c[-1] = 1.0
    u = rng.uniform(0.0, 1.0 / n) + np.arange(n) / n
    return np.minimum(np.searchsorted(c, u, side="left"), n - 1)


class HandParticleFilter:
    """Particle filter of one hand track, initialised with all particles at ``x1`` (velocity 0)."""

    def __init__(self, x1: np.ndarray, params: PFParams | None = None, n_clusters: int = 4,
                 rng: np.random.Generator | None = None) -> None:  # fmt: skip
        self.params = params or PFParams()
        self.n_clusters = int(n_clusters)
        self.rng = rng or np.random.default_rng(0)
        n = self.params.n_particles
        x1 = np.asarray(x1, float).copy()
        x1[4:] = 0.0
        self.particles = np.tile(x1, (n, 1))
        self.weights = np.full(n, 1.0 / n)
        self.estimate = x1.copy()
        self.n_eff = float(n)
        self.det_fraction = 0.0
        self.resampled = False

    def boxes_for_roi(self) -> np.ndarray:
        """The particles' states (for the ROI of the next step)."""
        return self.particles

    def reseed(self, state: np.ndarray, feats: HandFeatures) -> bool:
        """Product addition: offer ``state`` (e.g. the tight box of the hand's own colour component) to the filter. If
        its likelihood beats the estimate's, the lighter half of the particles is replaced by it, weighted above the
        heaviest particle by the likelihood ratio, and the estimate recomputed; returns whether it was taken."""
        lik, _ = observe(np.stack([np.asarray(state, float), self.estimate]), feats, self.n_clusters, self.params)
        if not lik[0] > lik[1]:
            return False
        n = len(self.particles)
        idx = np.argsort(self.weights)[: n // 2]
        w = self.weights.copy()
        w[idx] = w.max() * (lik[0] / lik[1] if lik[1] > 0 else 2.0)
        self.particles[idx] = state
        self.weights = w / w.sum()
        self.estimate = mode_estimate(self.particles, self.weights)
        return True

    def set_state(self, state: np.ndarray) -> None:
        """Put every particle at ``state`` (px, px/frame) with equal weights."""
        self.particles = np.tile(np.asarray(state, float), (len(self.particles), 1))
        self.weights = np.full(len(self.particles), 1.0 / len(self.particles))
        self.estimate = np.asarray(state, float).copy()

    def coast(self, velocity: np.ndarray | None = None) -> None:
        """Constant-velocity move of every particle (no measurement): x ← x + x'; with ``velocity`` (px/frame) every
        particle takes that velocity first."""
        if velocity is not None:
            self.particles[:, 4:6] = velocity
        self.particles[:, :2] += self.particles[:, 4:6]
        self.estimate = mode_estimate(self.particles, self.weights)

    def step(self, feats: HandFeatures, image_size: tuple[int, int], avoid: np.ndarray | None = None) -> np.ndarray:
        """One step of Algorithm 10 on the frame's features; returns the MMSE estimate (6,). ``avoid``: inclusive
        boxes [M, 4] (working px) of the other tracks' predicted boxes; each particle's likelihood is multiplied by
        the exclusion factor of :mod:`tracker.hands.exclusion` (None: no factor, the thesis's step)."""
        prm = self.params
        n = len(self.particles)
        W, H = image_size
        ox, oy = float(feats.roi[0]), float(feats.roi[1])
        stats = box_stats_per_particle(self.particles, feats, self.n_clusters, prm.n_r)
        cent = np.stack(feats.centf).astype(np.float64)
        u3 = self.rng.random((n, 3))
        z = self.rng.standard_normal((n, 3, 2))
        new, det = _propagate(self.particles, stats, cent, feats.cc, feats.n_comp, feats.cc_area, feats.cc_box,
                              feats.cc_cut, ox, oy, float(W), float(H), u3, z, prm.n_min, prm.tau_d, prm.sigma_p0,
                              prm.sigma_s0, prm.sigma_vfb)  # fmt: skip
        if len(feats.anchors):
            # wrist cut (product extension of the section-6 mode, tracker.hands.palm_cut): if the track's predicted
            # box overlaps a palm anchor, every particle not in the section-6 mode takes the anchor's box, and so
            # does a particle whose section-6 box is the whole arm around the anchor
            e = self.estimate
            k = int(match_anchor(np.array([box_of(e[0] + e[4], e[1] + e[5], e[2], e[3])], np.float64),
                                 feats.anchors)[0])  # fmt: skip
            if k >= 0:
                _take_anchor(new, det, self.particles, np.ascontiguousarray(feats.anchors[k], np.float64),
                             ANCHOR_INSIDE)  # fmt: skip
        lik, _ = observe(new, feats, self.n_clusters, prm)
        if avoid is not None and len(avoid):
            lik = lik * exclusion_factors(new, np.ascontiguousarray(avoid, np.float64), EXCL_F0, EXCL_KAPPA)
        w = self.weights * lik
        s = w.sum()
        if not np.isfinite(s) or s <= 0:
            w = np.full(n, 1.0 / n)
        else:
            w = w / s
        self.n_eff = float(1.0 / np.sum(w**2))
        self.det_fraction = float(det.mean())
        self.resampled = self.n_eff < prm.nt
        if self.resampled:
            idx = systematic_resample(w, self.rng)
            new = new[idx]
            w = np.full(n, 1.0 / n)
        self.particles = new
        self.weights = w
        self.estimate = mode_estimate(new, w)
        return self.estimate
