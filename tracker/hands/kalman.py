"""The thesis's Kalman-filter reference tracker for one hand (hand-tracking spec §5, Algorithm 11).

Same state and features as the particle filter. Dynamics: constant velocity, size scaled by the mean ratio of both
forward flows (eqs. 6.36–6.38), Q = blockdiag(σ²I, Q^s, σ²I) with σ = 2 (eqs. 6.39–6.42). Observation
(x, y, x', y') from the coverage-weighted forward PMC motion (eqs. 6.44–6.47), checked against the colour mask
(τ^c = 0.6, eq. 6.48) with an 11×11 local translation search if it fails (ties: smallest |dx| + |dy|), R from the
backward flows' covariance (eqs. 6.52–6.53). In the section-6 mode y = the certain state, H = I_6, R = σ_δ²I.
Fallback (§14.8): no colour pixel in the predicted box or an empty mask → prediction only.
"""

from __future__ import annotations

import numpy as np

from tracker.hands.box_stats import box_of, flow_cov, mask_count, transition_stats
from tracker.hands.certainty import TAU_D, certain_state
from tracker.hands.features import HandFeatures
from tracker.hands.palm_cut import anchor_state, holds_anchor, match_anchor

SIGMA_Q = 2.0
TAU_C = 0.6
SEARCH = 5
SIGMA_DELTA = 1e-6


class HandKalmanFilter:
    """Kalman filter of one hand track, initialised at ``x1`` (velocity 0) with P_1 = 0; ``sigma_q`` = σ_{p,0} =
    σ_{v,0} (2 px in full-resolution pixels, eq. 6.40)."""

    def __init__(self, x1: np.ndarray, n_clusters: int = 4, n_r: int = 256, sigma_q: float = SIGMA_Q) -> None:
        self.sigma_q = float(sigma_q)
        self.m = np.asarray(x1, float).copy()
        self.m[4:] = 0.0
        self.P = np.zeros((6, 6))
        self.n_clusters = int(n_clusters)
        self.n_r = int(n_r)
        self.estimate = self.m.copy()
        self.det_fraction = 0.0
        self.n_eff = 1.0

    def boxes_for_roi(self) -> np.ndarray:
        return self.m[None]

    def set_state(self, state: np.ndarray) -> None:
        """Set the state mean to ``state`` (px, px/frame); the covariance stays."""
        self.m = np.asarray(state, float).copy()
        self.estimate = self.m.copy()

    def coast(self, velocity: np.ndarray | None = None) -> None:
        """Constant-velocity prediction without a measurement: position += velocity (with ``velocity`` (px/frame),
        the state takes that velocity first)."""
        self.m = self.m.copy()
        if velocity is not None:
            self.m[4:6] = velocity
        self.m[:2] += self.m[4:6]
        self.estimate = self.m.copy()

    def step(self, feats: HandFeatures, image_size: tuple[int, int]) -> np.ndarray:
        m0 = self.m
        ox, oy = float(feats.roi[0]), float(feats.roi[1])
        u0, v0, u1, v1 = box_of(m0[0] - ox, m0[1] - oy, m0[2], m0[3])
        st = [transition_stats(u0, v0, u1, v1, feats.mprev, feats.ff[a], feats.labf[a], self.n_clusters, self.n_r)
              for a in range(2)]  # fmt: skip
        rx = 0.5 * (st[0][5] + st[1][5])
        ry = 0.5 * (st[0][6] + st[1][6])
        s2x = 0.5 * (st[0][7] + st[1][7])
        s2y = 0.5 * (st[0][8] + st[1][8])
        A = np.eye(6)
        A[0, 4] = A[1, 5] = 1.0
        A[2, 2] = rx
        A[3, 3] = ry
        q = self.sigma_q**2
        Q = np.diag([q, q, m0[2] ** 2 * s2x, m0[3] ** 2 * s2y, q, q])
        mp = A @ m0
        Pp = A @ self.P @ A.T + Q
        # forward PMC centroids and the section-6 test
        cent = np.full((2, 2), np.nan)
        cover = np.zeros(2)
        for a in range(2):
            mi = int(st[a][1])
            if mi >= 0:
                cent[a] = feats.centf[a][mi]
                lab = feats.labf[a]
                H_, W_ = lab.shape
                cu0, cv0, cu1, cv1 = max(u0, 0), max(v0, 0), min(u1, W_ - 1), min(v1, H_ - 1)
                cover[a] = float(np.count_nonzero(lab[cv0 : cv1 + 1, cu0 : cu1 + 1] == mi))
        ratio = np.array([[st[0][5], st[0][6]], [st[1][5], st[1][6]]])
        passed, cert = certain_state(m0[0], m0[1], m0[2], m0[3], cent, ratio, feats.cc, feats.n_comp, feats.cc_area,
                                     feats.cc_box, feats.cc_cut, ox, oy, TAU_D)  # fmt: skip
        if len(feats.anchors):
            k = match_anchor(np.array([box_of(mp[0], mp[1], mp[2], mp[3])], np.float64), feats.anchors)[0]
            # wrist cut (tracker.hands.palm_cut) as the section-6 observation, also instead of a section-6 box that
            # is the whole arm around the anchor
            if k >= 0 and (not passed or holds_anchor(box_of(cert[0], cert[1], cert[2], cert[3]), feats.anchors[k])):
                passed, cert = True, anchor_state(feats.anchors[k], (m0[0], m0[1]))
        self.det_fraction = 1.0 if passed else 0.0
        if passed:
            Hm = np.eye(6)
            y = cert
            R = SIGMA_DELTA**2 * np.eye(6)
        else:
            if cover.sum() <= 0 or not feats.mcur.any():
                self.m, self.P = mp, Pp
                self.estimate = self.m.copy()
                return self.estimate
            wts = cover / cover.sum()
            cf = sum(wts[a] * np.nan_to_num(cent[a]) for a in range(2))
            xh = np.array([m0[0] + cf[0], m0[1] + cf[1], rx * m0[2], ry * m0[3], cf[0], cf[1]])
            xh = self._coverage_search(xh, feats)
            b = box_of(xh[0] - ox, xh[1] - oy, xh[2], xh[3])
            covs = [flow_cov(*b, feats.mcur, feats.fb[a]) for a in range(2)]
            Rv = 0.5 * np.array([[covs[0][0] + covs[1][0], covs[0][1] + covs[1][1]],
                                 [covs[0][1] + covs[1][1], covs[0][2] + covs[1][2]]])  # fmt: skip
            R = np.zeros((4, 4))
            R[:2, :2] = Rv
            R[2:, 2:] = Rv
            Hm = np.zeros((4, 6))
            Hm[0, 0] = Hm[1, 1] = Hm[2, 4] = Hm[3, 5] = 1.0
            y = np.array([xh[0], xh[1], xh[0] - m0[0], xh[1] - m0[1]])
        S = Hm @ Pp @ Hm.T + R
        K = Pp @ Hm.T @ np.linalg.inv(S)
        self.m = mp + K @ (y - Hm @ mp)
        self.P = (np.eye(6) - K @ Hm) @ Pp
        self.m[2] = min(max(self.m[2], 4.0), image_size[0])
        self.m[3] = min(max(self.m[3], 4.0), image_size[1])
        self.estimate = self.m.copy()
        return self.estimate

    @staticmethod
    def _coverage_search(xh: np.ndarray, feats: HandFeatures) -> np.ndarray:
        """x̂^0 if its box's colour coverage ≥ τ^c, else the best integer shift in [−5, 5]² (eqs. 6.48–6.50)."""
        ox, oy = feats.roi[0], feats.roi[1]
        u0, v0, u1, v1 = box_of(xh[0] - ox, xh[1] - oy, xh[2], xh[3])
        n, area = mask_count(u0, v0, u1, v1, feats.mcur)
        if area > 0 and n / area >= TAU_C:
            return xh
        best = (-1.0, 0, 0, 0)
        for dy in range(-SEARCH, SEARCH + 1):
            for dx in range(-SEARCH, SEARCH + 1):
                n, area = mask_count(u0 + dx, v0 + dy, u1 + dx, v1 + dy, feats.mcur)
                cov = n / area if area > 0 else 0.0
                key = (cov, -(abs(dx) + abs(dy)))
                if key > (best[0], best[1]):
                    best = (cov, -(abs(dx) + abs(dy)), dx, dy)
        out = xh.copy()
        out[0] += best[2]
        out[1] += best[3]
        return out
