"""Per-box statistics of the hand trackers (numba kernels), in region-of-interest (ROI) pixel coordinates.

A state is x = (x, y, w, h, x', y') (hand-tracking spec §2, eq. 6.1): box centre (px), width and height (px) and
velocity (px/frame), image coordinates (x right, y down, pixel centres at integers). Its box B(x) covers columns
round(x − w/2) … round(x + w/2) and rows round(y − h/2) … round(y + h/2), inclusive (spec §2, product choice);
the kernels take such inclusive boxes already shifted into the ROI and clip them to it (pixels outside the ROI are
not counted; the ROI holds every particle's box with a margin, spec §14.2).

* :func:`transition_stats`: for one box and one forward flow version, the colour-mask pixel count, the principal
  motion component (eq. 6.6), the flow covariance Σ^v (§4.2) and the scale ratios r, s² (§3.5, errata E1, E5);
* :func:`box_observation` and :func:`observation_likelihood`: the observation model p(y_k | x_k) (eqs.
  6.20–6.31), split into the part that depends on the box only and the part that needs the velocity;
* :func:`dominant_component`: the colour component covering most of a box (eq. 6.56);
* :func:`box_of`: the inclusive integer box of a state.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

EPS_COV = 0.01
"""Ridge ε (px²) added to every sample covariance (§14.8)."""


@nb.njit(cache=True, nogil=True)
def box_of(x: float, y: float, w: float, h: float) -> tuple[int, int, int, int]:
    """Inclusive integer box (u0, v0, u1, v1) of a state's centre and size (round half to even, as numpy)."""
    return (int(np.rint(x - w / 2.0)), int(np.rint(y - h / 2.0)), int(np.rint(x + w / 2.0)), int(np.rint(y + h / 2.0)))


def box_area(b) -> int:
    """Pixels of an inclusive box (u0, v0, u1, v1); 0 or less for an empty one."""
    return (b[2] - b[0] + 1) * (b[3] - b[1] + 1)


@nb.njit(cache=True, nogil=True)
def _clip(u0, v0, u1, v1, W, H):
    return max(u0, 0), max(v0, 0), min(u1, W - 1), min(v1, H - 1)


@nb.njit(cache=True, nogil=True)
def transition_stats(u0, v0, u1, v1, mask, flow, labels, n_clusters, n_r):
    """Statistics of the forward flow ``flow`` [h, w, 2] on B ∩ ``mask`` for the inclusive box (u0..u1, v0..v1).

    Returns (n, m, s00, s01, s11, rx, ry, s2x, s2y): n = |B ∩ B^c|; m = PMC index (eq. 6.6) of ``labels`` in the box
    (−1 if no cluster pixel lies in it); Σ^v = [[s00, s01], [s01, s11]] the sample covariance (normaliser n − 1,
    plus ε; 1 px²·I with fewer than 3 vectors); r, s² = mean and variance (n − 1) of the pairwise distance ratios
    along x and y on a spatially uniform subsample of at most ``n_r`` pixels, pairs with equal coordinates excluded
    (r = 1, s² = 0 with fewer than 2 valid pairs).
    """
    H, W = mask.shape
    u0, v0, u1, v1 = _clip(u0, v0, u1, v1, W, H)
    counts = np.zeros(n_clusters, np.int64)
    n = 0
    su = 0.0
    sv = 0.0
    suu = 0.0
    suv = 0.0
    svv = 0.0
    for v in range(v0, v1 + 1):
        for u in range(u0, u1 + 1):
            lab = labels[v, u]
            if lab >= 0:
                counts[lab] += 1
            if mask[v, u]:
                n += 1
                fu = flow[v, u, 0]
                fv = flow[v, u, 1]
                su += fu
                sv += fv
                suu += fu * fu
                suv += fu * fv
                svv += fv * fv
    m = -1
    best = 0
    for i in range(n_clusters):
        if counts[i] > best:
            best = counts[i]
            m = i
    if n >= 3:
        mu = su / n
        mv = sv / n
        s00 = (suu - n * mu * mu) / (n - 1) + EPS_COV
        s01 = (suv - n * mu * mv) / (n - 1)
        s11 = (svv - n * mv * mv) / (n - 1) + EPS_COV
    else:
        s00, s01, s11 = 1.0, 0.0, 1.0
    # scale ratios on a uniform subsample (every stride-th mask pixel in raster order)
    rx, ry, s2x, s2y = 1.0, 1.0, 0.0, 0.0
    if n >= 2:
        stride = (n + n_r - 1) // n_r
        k = (n + stride - 1) // stride
        px = np.empty(k)
        py = np.empty(k)
        qx = np.empty(k)
        qy = np.empty(k)
        j = 0
        c = 0
        for v in range(v0, v1 + 1):
            for u in range(u0, u1 + 1):
                if mask[v, u]:
                    if c % stride == 0 and j < k:
                        px[j] = u
                        py[j] = v
                        qx[j] = u + flow[v, u, 0]
                        qy[j] = v + flow[v, u, 1]
                        j += 1
                    c += 1
        nx = 0
        ny = 0
        sx = 0.0
        sxx = 0.0
        sy = 0.0
        syy = 0.0
        for a in range(j):
            for b in range(a):
                dx = abs(px[a] - px[b])
                if dx > 0:
                    r = abs(qx[a] - qx[b]) / dx
                    nx += 1
                    sx += r
                    sxx += r * r
                dy = abs(py[a] - py[b])
                if dy > 0:
                    r = abs(qy[a] - qy[b]) / dy
                    ny += 1
                    sy += r
                    syy += r * r
        if nx >= 2:
            rx = sx / nx
            s2x = max(0.0, (sxx - nx * rx * rx) / (nx - 1))
        if ny >= 2:
            ry = sy / ny
            s2y = max(0.0, (syy - ny * ry * ry) / (ny - 1))
    return n, m, s00, s01, s11, rx, ry, s2x, s2y


@nb.njit(cache=True, nogil=True)
def mask_count(u0, v0, u1, v1, mask):
    """(|B ∩ mask|, |B|) for an inclusive box clipped to the ROI."""
    H, W = mask.shape
    u0, v0, u1, v1 = _clip(u0, v0, u1, v1, W, H)
    n = 0
    for v in range(v0, v1 + 1):
        for u in range(u0, u1 + 1):
            if mask[v, u]:
                n += 1
    area = max(0, u1 - u0 + 1) * max(0, v1 - v0 + 1)
    return n, area


@nb.njit(cache=True, nogil=True)
def flow_cov(u0, v0, u1, v1, mask, flow):
    """Sample covariance (s00, s01, s11) of ``flow`` on B ∩ ``mask`` (n − 1, plus ε; 1 px²·I with < 3 vectors)."""
    H, W = mask.shape
    u0, v0, u1, v1 = _clip(u0, v0, u1, v1, W, H)
    n = 0
    su = sv = suu = suv = svv = 0.0
    for v in range(v0, v1 + 1):
        for u in range(u0, u1 + 1):
            if mask[v, u]:
                fu = flow[v, u, 0]
                fv = flow[v, u, 1]
                n += 1
                su += fu
                sv += fv
                suu += fu * fu
                suv += fu * fv
                svv += fv * fv
    if n < 3:
        return 1.0, 0.0, 1.0
    mu = su / n
    mv = sv / n
    s00 = (suu - n * mu * mu) / (n - 1) + EPS_COV
    return s00, (suv - n * mu * mv) / (n - 1), (svv - n * mv * mv) / (n - 1) + EPS_COV


@nb.njit(cache=True, nogil=True)
def box_observation(u0, v0, u1, v1, mask, lab1, lab2, n_clusters, d2_scale):
    """Pixel statistics of the observation model for one inclusive box, clipped to the ROI first (its outline is
    the clipped box's one-pixel border, d the distance to it, closed form for a rectangle; eqs. 6.22–6.29).

    Returns [a_{c,1}, a_{c,2}, area, m1, |B^{b,1,m1} ∩ B|, m2, |B^{b,2,m2} ∩ B|] (m = −1 when no cluster pixel lies in
    the box); ``d2_scale`` = 80 px² (eq. 6.22) in the working resolution's pixels."""
    out = np.zeros(7)
    H, W = mask.shape
    u0, v0, u1, v1 = _clip(u0, v0, u1, v1, W, H)
    if u1 < u0 or v1 < v0:
        out[3] = -1.0
        out[5] = -1.0
        return out
    sw = 0.0
    swm = 0.0
    n_out = 0
    n_out_m = 0
    c1 = np.zeros(n_clusters, np.int64)
    c2 = np.zeros(n_clusters, np.int64)
    for v in range(v0, v1 + 1):
        dv = min(v - v0, v1 - v)
        for u in range(u0, u1 + 1):
            d = min(u - u0, u1 - u, dv)
            wgt = 1.0 - math.exp(-(d * d) / d2_scale)
            m = mask[v, u]
            sw += wgt
            if m:
                swm += wgt
            if d == 0:
                n_out += 1
                if m:
                    n_out_m += 1
            a = lab1[v, u]
            if a >= 0:
                c1[a] += 1
            b = lab2[v, u]
            if b >= 0:
                c2[b] += 1
    out[0] = swm / sw if sw > 0 else 0.0
    out[1] = n_out_m / n_out if n_out > 0 else 0.0
    out[2] = (u1 - u0 + 1) * (v1 - v0 + 1)
    for alpha in range(2):
        cnt = c1 if alpha == 0 else c2
        m = -1
        best = 0
        for i in range(n_clusters):
            if cnt[i] > best:
                best = cnt[i]
                m = i
        out[3 + 2 * alpha] = m
        out[4 + 2 * alpha] = best
    return out


@nb.njit(cache=True, nogil=True)
def observation_likelihood(obs, vx, vy, cent1, cent2, ac_hat, am_hat, v2_scale):
    """p(y_k | x_k) (eq. 6.20, π_c = π_m = 0.5) from :func:`box_observation`'s ``obs`` and the state's velocity:
    p_c = g_{c,1}·g_{c,2} (eqs. 6.24, 6.26), p_m = g_{m,1}·g_{m,2} (eqs. 6.30, 6.31 corrected), ``ac_hat`` = â_{c,1},
    ``am_hat`` = â_{m,1}, ``v2_scale`` = 7 (px/frame)² of eq. 6.31 in working pixels; p_m = 0 without a PMC."""
    if obs[2] <= 0:
        return 0.0
    ac1 = obs[0]
    ac2 = obs[1]
    pc = math.exp(-10.0 * (ac1 - ac_hat) ** 2) * math.exp(-5.0 * ac2 * ac2)
    if obs[3] < 0 or obs[5] < 0:
        return 0.5 * pc
    am = 0.5 * (obs[4] + obs[6]) / obs[2]
    gm2 = 0.0
    for alpha in range(2):
        cent = cent1 if alpha == 0 else cent2
        m = int(obs[3 + 2 * alpha])
        du = -cent[m, 0] - vx
        dv = -cent[m, 1] - vy
        gm2 += 0.5 * math.exp(-(du * du + dv * dv) / v2_scale)
    return 0.5 * pc + 0.5 * math.exp(-10.0 * (am - am_hat) ** 2) * gm2


@nb.njit(cache=True, nogil=True)
def dominant_component(u0, v0, u1, v1, cc, n_comp):
    """(label, |component ∩ B|) of the colour component (labels ``cc``, 0 = none, 1..n_comp) that covers most pixels
    of the inclusive box; label 0 if none does."""
    H, W = cc.shape
    u0, v0, u1, v1 = _clip(u0, v0, u1, v1, W, H)
    counts = np.zeros(n_comp + 1, np.int64)
    for v in range(v0, v1 + 1):
        for u in range(u0, u1 + 1):
            counts[cc[v, u]] += 1
    best = 0
    lab = 0
    for i in range(1, n_comp + 1):
        if counts[i] > best:
            best = counts[i]
            lab = i
    return lab, best


@nb.njit(cache=True, nogil=True)
def boxes_of(states, ox, oy):
    """Inclusive integer boxes [N, 4] (:func:`box_of`) of states [N, ≥4] shifted by (−``ox``, −``oy``) into the ROI."""
    n = states.shape[0]
    out = np.empty((n, 4), np.int64)
    for i in range(n):
        u0, v0, u1, v1 = box_of(states[i, 0] - ox, states[i, 1] - oy, states[i, 2], states[i, 3])
        out[i, 0] = u0
        out[i, 1] = v0
        out[i, 2] = u1
        out[i, 3] = v1
    return out


@nb.njit(cache=True, nogil=True)
def first_of_each_box(boxes):
    """Per row of ``boxes`` [N, 4], the index of the first row with the same box (statistics are computed once per
    distinct box: after resampling many particles share one)."""
    n = boxes.shape[0]
    first = np.empty(n, np.int64)
    for i in range(n):
        first[i] = i
        for j in range(i):
            if (first[j] == j and boxes[j, 0] == boxes[i, 0] and boxes[j, 1] == boxes[i, 1]
                    and boxes[j, 2] == boxes[i, 2] and boxes[j, 3] == boxes[i, 3]):  # fmt: skip
                first[i] = j
                break
    return first


@nb.njit(cache=True, nogil=True)
def observe_states(states, ox, oy, mask, lab1, lab2, n_clusters, d2_scale, cent1, cent2, ac_hat, am_hat, v2_scale):
    """(p(y_k | x_k), a_{c,1}) of every state [N, 6] (ROI origin ``ox``, ``oy``): :func:`box_observation` once per
    distinct box, then :func:`observation_likelihood` with each state's velocity."""
    boxes = boxes_of(states, ox, oy)
    first = first_of_each_box(boxes)
    n = states.shape[0]
    obs = np.empty((n, 7))
    lik = np.empty(n)
    ac1 = np.empty(n)
    for i in range(n):
        if first[i] == i:
            obs[i] = box_observation(boxes[i, 0], boxes[i, 1], boxes[i, 2], boxes[i, 3], mask, lab1, lab2, n_clusters,
                                     d2_scale)  # fmt: skip
        else:
            obs[i] = obs[first[i]]
        lik[i] = observation_likelihood(obs[i], states[i, 4], states[i, 5], cent1, cent2, ac_hat, am_hat, v2_scale)
        ac1[i] = obs[i, 0]
    return lik, ac1


@nb.njit(cache=True, nogil=True)
def transition_stats_of_states(states, ox, oy, mask, flow1, flow2, lab1, lab2, n_clusters, n_r):
    """:func:`transition_stats` [N, 2, 9] of every state's box (ROI origin ``ox``, ``oy``) on both forward flow
    versions, once per distinct box."""
    boxes = boxes_of(states, ox, oy)
    first = first_of_each_box(boxes)
    n = states.shape[0]
    out = np.empty((n, 2, 9))
    for i in range(n):
        if first[i] != i:
            out[i] = out[first[i]]
            continue
        u0, v0, u1, v1 = boxes[i, 0], boxes[i, 1], boxes[i, 2], boxes[i, 3]
        for a in range(2):
            if a == 0:
                r = transition_stats(u0, v0, u1, v1, mask, flow1, lab1, n_clusters, n_r)
            else:
                r = transition_stats(u0, v0, u1, v1, mask, flow2, lab2, n_clusters, n_r)
            out[i, a, 0] = r[0]
            out[i, a, 1] = r[1]
            out[i, a, 2] = r[2]
            out[i, a, 3] = r[3]
            out[i, a, 4] = r[4]
            out[i, a, 5] = r[5]
            out[i, a, 6] = r[6]
            out[i, a, 7] = r[7]
            out[i, a, 8] = r[8]
    return out
