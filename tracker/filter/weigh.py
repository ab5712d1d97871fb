"""Weighing stage: the coordinate passes of Algorithm 5 (spec sections 4 and 9).

For each part k in turn: sample its noise and propagate it (:mod:`tracker.filter.predict`), force connection
particles (Algorithm 6), re-render what changed (:mod:`tracker.filter.render`: z-buffer over all parts at the
evaluated pixels), update the per-particle log-likelihood relative to the no-object hypothesis
(:mod:`tracker.filter.depth_likelihood`) plus the log penalties and priors, multiply the carried weights by
exp(ℓ_k − ℓ_{k−1}) and resample (:mod:`tracker.filter.resampling`) when D_KL(w‖U) exceeds D_KL,max, copying every
per-particle buffer with the particles (the pixel buffers in place, only the rows that change).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numba as nb
import numpy as np

from tracker.filter import hidden_parts, predict, render
from tracker.filter.colour_input import color_masks
from tracker.filter.connection_particles import apply_connections
from tracker.filter.depth_likelihood import (
    occlusion_affine,
    pixel_constants,
    predicted_occlusion,
    update_log_likelihood,
)
from tracker.filter.frame_context import FrameContext, PassResult
from tracker.filter.penalties import (
    bounding_radii,
    intersection_log_penalty,
    lowest_heights,
    obb_overlap,
    spheres_apart,
    table_log_penalty,
    world_centres,
)
from tracker.filter.resampling import reweigh, systematic_resample, take_rows_inplace

if TYPE_CHECKING:
    from tracker.filter.particle_filter import MultiObjectTracker


def coordinate_passes(trk: MultiObjectTracker, ctx: FrameContext, u: np.ndarray, noise_scale: np.ndarray, detections,
                      detected: np.ndarray, evaluated: tuple[np.ndarray, np.ndarray], pred) -> PassResult:
    """Run the K coordinate passes on the evaluated pixels; ``pred``: the deterministic prediction (p, R, v)."""
    cfg = trk.config
    intr = trk.intrinsics
    depth = ctx.depth
    now = ctx.now
    n, k = cfg.n_particles, len(trk.parts)
    table_plane = ctx.table_plane
    plane = table_plane if cfg.use_table_penalty else None
    support_plane = table_plane if cfg.support_prior_sigma > 0 else None
    # last frame's particles, read one part at a time (its pass's reference poses); a resampling composes its
    # indices into ``perm`` (the frame's rows in the current order, None = as they are) instead of gathering them
    perm = None
    p_cur, R_cur, v_cur = pred
    pix, regions = evaluated
    loc = np.full(regions.shape, -1, np.int64)
    loc[regions] = np.arange(int(regions.sum()), dtype=np.int64)  # one depth column per (part, pixel)
    z = depth.reshape(-1)[trk._vs[trk._gj[pix]] * intr.width + trk._us[trk._gi[pix]]].astype(np.float64)
    s, e, log_po_inf = pixel_constants(z, trk.likelihood)
    rays, pu, pv = trk._rays[pix], trk._pu[pix], trk._pv[pix]
    gi, gj = trk._gi[pix], trk._gj[pix]
    npix = pix.size
    if cfg.use_occlusion_model:
        last = trk.occ_time[pix]
        dtp = np.where(np.isfinite(last), now - last, 0.0)
        ab = occlusion_affine(dtp, cfg.p_occ_given_vis, cfg.p_occ_given_occ)
        a, b = ab if ab is not None else (np.ones(npix, np.float32), np.zeros(npix, np.float32))
        # ô' = max(ô, o_hand·H): pixels under a hand are likely occluded (hand spec §14.5)
        hand_prior = ctx.occluder_prior(trk._us, trk._vs, gi, gj)
        floor = (np.full(npix, -np.inf, np.float32) if hand_prior is None
                 else np.ascontiguousarray(hand_prior, np.float32))
        o_hat = predicted_occlusion(trk.occ, pix, a, b, floor)  # (N, P), the rows of ``pix`` predicted, transposed
    else:
        o_hat = np.zeros((n, npix), np.float32)

    # full render + likelihood at the deterministic prediction
    t1 = time.perf_counter()
    m_cols = int(regions.sum())
    D = trk._buffer("D0", (n, m_cols), np.float32, np.inf)
    dirty = trk._buffer("dirty", (n, npix), np.uint8, 0)
    all_particles = np.arange(n, dtype=np.int64)
    all_pix = np.arange(npix, dtype=np.int64)
    if k > 1:  # with one part, its own pass below renders it everywhere it can be: no render needed here
        for i in range(k):
            # only the pixels of the part's region (loc ≥ 0): the renderers skip every other pixel anyway
            render.render(trk, i, p_cur, R_cur, all_particles, rays, pu, pv, gi, gj, np.flatnonzero(regions[i]), D,
                          loc, dirty)
    t2 = time.perf_counter()
    # C, Q, F are written over all pixels by the first likelihood call below (``fresh``: uncovered where no part was
    # drawn, consistent with D = inf), not filled first
    C = trk._buffer("C0", (n, npix), np.float32)
    Q = trk._buffer("Q0", (n, npix), np.float32)
    F = trk._buffer("F0", (n, npix), np.int8)
    ell = np.zeros(n)
    anc = np.arange(n)
    prm = trk.likelihood
    beta, lam, tail = prm.tail_weight, prm.occluder_rate, prm.tail_weight / prm.max_depth
    use_occ = bool(cfg.use_occlusion_model)
    alpha = float(cfg.likelihood_exponent)
    cmask, cvalid = color_masks(trk, detections, gi, gj)
    occ_cap = float(cfg.occluded_evidence_cap)
    update_log_likelihood(D, loc, all_pix, z, s, e, log_po_inf, o_hat, anc, C, Q, F, ell, beta, lam, tail, use_occ,
                          dirty, alpha, cmask, cvalid, occ_cap, True)
    t_render = t2 - t1
    t_lik = time.perf_counter() - t2
    t_res = 0.0
    t_pen = 0.0
    ell_prev = np.zeros(n)  # ℓ_0 = 0 at the start of each frame
    log_w = trk.log_w.copy()
    w = np.empty(n)  # this pass's normalised weights (reweigh)
    n_resampled = 0

    # 3. coordinate passes (Algorithm 5); unlocked hints move only parts estimated visible enough
    forceable = trk.visibility >= cfg.hint_min_visibility  # previous frame's occlusion estimate
    if cfg.hint_min_visibility > 0 and cfg.use_color_input and detections:
        forceable &= detected  # and a reliable colour blob now: the hand may have covered the part this frame
    penalties = PenaltyTerms(trk, plane)
    priors = hidden_parts.PriorTerms(trk, support_plane)
    skip = trk._quiet_now  # decided before the evaluated pixels (filter/quiet_parts.py)
    first = True
    # the rendered depths and cached pixel terms are not read after the frame's last pass: its resampling leaves them
    last_pass = max((j for j in range(k) if not skip[j]), default=0)
    for i in range(k + 1):
        if i == k:  # every pass skipped: the weights still take the likelihood of the prediction (and penalties)
            if not first:
                break
            i, changed_objs = 0, None
        elif skip[i]:
            continue
        else:
            changed_objs = {i}
        if changed_objs is None:
            tb = tc = time.perf_counter()
            ta = tb
        else:
            ta, tb, tc, changed_objs = _pass_render_likelihood(
                trk, i, all_particles if perm is None else perm, p_cur, R_cur, v_cur, u, noise_scale, forceable, rays,
                pu, pv, gi, gj,
                D, loc, dirty, all_particles, z, s, e, log_po_inf, o_hat, anc, C, Q, F, ell, beta, lam, tail, use_occ,
                alpha, cmask, cvalid, occ_cap)
        rest, support = priors.total(p_cur, R_cur, None if first else changed_objs)
        ell_tot = ell + penalties.total(p_cur, R_cur, None if first else changed_objs) + rest + support
        first = False
        td = time.perf_counter()
        # log_w += ℓ − ℓ_prev, normalised into w, log_w = log w and D_KL(w‖U): one kernel (the numpy form's values)
        kl = reweigh(log_w, ell_tot, ell_prev, w)
        ell_prev = ell_tot
        if kl > cfg.kl_max:
            idx = systematic_resample(w, trk.rng)
            perm = idx if perm is None else perm[idx]
            p_cur, R_cur, v_cur = _take(p_cur, idx), _take(R_cur, idx), _take(v_cur, idx)
            # dirty flags are all clear; ô is reached through anc
            if i != last_pass:
                take_rows_inplace(D, idx)
                take_rows_inplace(C, idx)
                penalties.take(idx)
                priors.take(idx)
            take_rows_inplace(Q, idx)
            take_rows_inplace(F, idx)
            ell, ell_prev, anc = ell[idx], ell_prev[idx], anc[idx]
            log_w = np.full(n, -np.log(n))
            n_resampled += 1
        te = time.perf_counter()
        t_render += tb - ta
        t_lik += tc - tb
        t_pen += td - tc
        t_res += te - td

    if cfg.quiet_keep_spread:
        # the skipped parts' particles get this frame's motion noise after the weighing (their likelihood was taken at
        # the prediction), so that their cloud keeps its spread for when they move again
        for i in np.flatnonzero(skip):
            predict.noisy_into(trk, all_particles if perm is None else perm, i, u[i], noise_scale[i], p_cur, R_cur,
                               v_cur)
    ctx.timings.update(render=t_render * 1e3, likelihood=t_lik * 1e3, penalties=t_pen * 1e3, resample=t_res * 1e3)
    return PassResult(p_cur, R_cur, v_cur, log_w, ell_prev, pix, Q, F, o_hat, anc, n_resampled)


def _take(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``a[idx]`` (rows), in place when ``a`` is C-contiguous (the passes' particle arrays are the frame's own: made by
    the prediction, not shared): :func:`~tracker.filter.resampling.take_rows_inplace` on its rows."""
    if a.flags.c_contiguous and a.shape[0] == idx.shape[0]:
        take_rows_inplace(a.reshape(a.shape[0], -1), idx)
        return a
    return a[idx]


def _pass_render_likelihood(trk, i, rows, p_cur, R_cur, v_cur, u, noise_scale, forceable, rays, pu,
                            pv, gi, gj, D, loc, dirty, all_particles, z, s, e, log_po_inf, o_hat, anc, C, Q, F, ell,
                            beta, lam, tail, use_occ, alpha, cmask, cvalid, occ_cap):
    """Part ``i``'s pass up to its likelihood: noisy propagation from last frame's particles ``rows`` (the current
    order: the frame's resamplings composed), connection particles, re-render of what changed and the likelihood
    update on those pixels (arrays updated in place). Returns the pass's clock readings before the render, before
    and after the likelihood, and the set of parts it moved."""
    cfg = trk.config
    k = len(trk.parts)
    rect = render.bbox(trk, i, p_cur[:, i], R_cur[:, i])  # where the part was drawn before this pass
    predict.noisy_into(trk, rows, i, u[i], noise_scale[i], p_cur, R_cur, v_cur)
    changed_objs = {i}
    forced = None
    if trk._hints and cfg.use_connection_particles:
        before_p = p_cur.copy()
        before_R = R_cur.copy()
        forced = apply_connections(p_cur, R_cur, trk._hints, forceable)
        forced[:, i] = False
        for o in range(k):
            if forced[:, o].any():
                changed_objs.add(o)
    # pixels whose depth may change: old and new projections of every changed part
    rect = render.union(rect, render.bbox(trk, i, p_cur[:, i], R_cur[:, i]))
    for o in changed_objs - {i}:
        sel = forced[:, o]
        rect = render.union(rect, render.bbox(trk, o, before_p[sel, o], before_R[sel, o]))
        rect = render.union(rect, render.bbox(trk, o, p_cur[sel, o], R_cur[sel, o]))
    subset = pixels_in_rect(pu, pv, float(rect[0]), float(rect[1]), float(rect[2]), float(rect[3]))
    ta = time.perf_counter()
    render.render(trk, i, p_cur, R_cur, all_particles, rays, pu, pv, gi, gj, subset, D, loc, dirty)
    for o in changed_objs - {i}:
        render.render(trk, o, p_cur, R_cur, np.nonzero(forced[:, o])[0].astype(np.int64), rays, pu, pv, gi, gj,
                     subset, D, loc, dirty)
    tb = time.perf_counter()
    update_log_likelihood(D, loc, subset, z, s, e, log_po_inf, o_hat, anc, C, Q, F, ell, beta,
                          lam, tail, use_occ, dirty, alpha, cmask, cvalid, occ_cap)
    tc = time.perf_counter()
    return ta, tb, tc, changed_objs


@nb.njit(cache=True)
def pixels_in_rect(pu: np.ndarray, pv: np.ndarray, umin: float, umax: float, vmin: float, vmax: float) -> np.ndarray:
    """Indices (int64, ascending) of the evaluated pixels at full-resolution ``(pu, pv)`` inside the rectangle
    ``umin <= u <= umax``, ``vmin <= v <= vmax`` (pixels; bounds may be infinite): ``np.nonzero`` of the four
    comparisons, in one pass."""
    out = np.empty(pu.shape[0], np.int64)
    n = 0
    for g in range(pu.shape[0]):
        if pu[g] >= umin and pu[g] <= umax and pv[g] >= vmin and pv[g] <= vmax:
            out[n] = g
            n += 1
    return out[:n]


def log_penalties(trk, p, R, plane) -> np.ndarray:
    """Log penalties (N,) of the particles (colour term, intersections, sinking into the table) computed from scratch;
    the passes keep them per part instead (:class:`PenaltyTerms`)."""
    cfg = trk.config
    out = np.zeros(p.shape[0])
    if trk._color_targets:
        intr = trk.intrinsics
        sig2 = cfg.color_likelihood_px**2
        for i, c, wgt in trk._color_targets:
            ctr = np.einsum("nij,j->ni", R[:, i], trk.center[i]) + p[:, i]
            z = np.maximum(ctr[:, 2], 1e-3)
            du = intr.fx * ctr[:, 0] / z + intr.cx - c[0]
            dv = intr.fy * ctr[:, 1] / z + intr.cy - c[1]
            d2 = du * du + dv * dv
            if cfg.color_term_dead_zone > 0:
                r_in = cfg.color_term_dead_zone * float(trk.half[i].min()) * intr.fx / z
                d2 = np.maximum(np.sqrt(d2) - r_in, 0.0) ** 2
            out -= 0.5 * wgt * np.minimum(d2, 9.0 * sig2) / sig2
    if cfg.use_intersection_penalty and len(trk.pairs):
        out += intersection_log_penalty(R, p, trk.center, trk.half, trk.pairs, cfg.contact_tolerance,
                                        cfg.lambda_i)
    if plane is not None and cfg.lambda_h > 0:
        hmin = lowest_heights(R, p, trk.hulls, plane[0], plane[1])
        out += table_log_penalty(hmin, cfg.lambda_h, cfg.table_tolerance)
    return out


def penalty_shapes(trk: MultiObjectTracker) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The parts' constants of :class:`PenaltyTerms`: smallest half extent (K,), the hull vertices of all parts
    stacked (V, 3, body frames) and each part's offset into them (K + 1,)."""
    k = len(trk.parts)
    half_min = np.array([float(h.min()) for h in trk.half], np.float64)
    hulls = [np.ascontiguousarray(h, np.float64).reshape(-1, 3) for h in trk.hulls]
    hull_off = np.zeros(k + 1, np.int64)
    hull_off[1:] = np.cumsum([h.shape[0] for h in hulls])
    hull_all = np.ascontiguousarray(np.concatenate(hulls)) if hulls else np.zeros((0, 3))
    return half_min, hull_all, hull_off


class PenaltyTerms:
    """:func:`log_penalties` of the particles during one frame's coordinate passes, kept per part (colour term,
    lowest height above the table) and per pair of parts (intersection), so that a pass recomputes only the terms
    of the parts it moved; :meth:`take` follows a resampling. The sum is formed exactly as :func:`log_penalties`
    forms it (same values; one numba kernel per call, :func:`_penalty_pass`)."""

    def __init__(self, trk: MultiObjectTracker, plane) -> None:
        cfg = trk.config
        self.trk = trk
        self.plane = plane
        n, k = cfg.n_particles, len(trk.parts)
        targets = trk._color_targets
        self.t_obj = np.array([int(t[0]) for t in targets], np.int64)
        self.t_uv = np.array([np.asarray(t[1], np.float64)[:2] for t in targets], np.float64).reshape(-1, 2)
        self.t_w = np.array([float(t[2]) for t in targets], np.float64)
        self.colour = np.zeros((len(targets), n))  # colour term per target (row) and particle
        self.t_done = np.zeros(len(targets), np.bool_)  # rows computed since the frame started
        self.use_pairs = bool(cfg.use_intersection_penalty and len(trk.pairs))
        self.pair_flags = np.zeros((n, max(len(trk.pairs), 1)), np.bool_)  # (N, M) bool per pair of trk.pairs
        self.use_table = plane is not None and cfg.lambda_h > 0
        self.heights = np.zeros((n, k))  # (N, K) lowest height of each part above the table
        self.half_min, self.hull_all, self.hull_off = trk._penalty_shapes  # per part, fixed: made once
        self.all_moved = np.ones(k, np.bool_)
        self.normal = np.zeros(3) if plane is None else np.asarray(plane[0], np.float64).reshape(3)
        self.offset = 0.0 if plane is None else float(plane[1])
        # the kernel's scalar settings, converted once a frame (not at each of the frame's passes)
        intr = trk.intrinsics
        self.scalars = (intr.fx, intr.fy, intr.cx, intr.cy, float(cfg.color_likelihood_px) ** 2,
                        float(cfg.color_term_dead_zone))
        self.pair_scalars = (float(cfg.contact_tolerance), float(np.log(cfg.lambda_i)) if self.use_pairs else 0.0)
        self.table_scalars = (float(cfg.lambda_h), float(cfg.table_tolerance))

    def total(self, p: np.ndarray, R: np.ndarray, changed: set[int] | None = None) -> np.ndarray:
        """The penalties (N,) at positions ``p`` (N, K, 3), rotations ``R`` (N, K, 3, 3), where only the parts in
        ``changed`` moved since the last call (``None``: all, e.g. the first call of the frame)."""
        trk = self.trk
        n, k = p.shape[0], p.shape[1]
        if changed is None:
            moved = self.all_moved  # read only by the kernel
        else:
            moved = np.zeros(k, np.bool_)
            moved[list(changed)] = True
        out = np.empty(n)
        _penalty_pass(np.ascontiguousarray(p, np.float64), np.ascontiguousarray(R, np.float64), moved,
                      changed is None, self.t_obj, self.t_uv, self.t_w, self.colour, self.t_done, trk.center,
                      self.half_min, *self.scalars, self.use_pairs, trk.half, trk.pairs, *self.pair_scalars,
                      self.pair_flags, self.use_table, self.hull_all, self.hull_off, self.normal, self.offset,
                      *self.table_scalars, self.heights, out)
        return out

    def take(self, idx: np.ndarray) -> None:
        """Follow a resampling: the particles are now the rows ``idx`` of the previous ones."""
        self.colour = self.colour[:, idx]
        self.pair_flags = self.pair_flags[idx]
        self.heights = self.heights[idx]


@nb.njit(cache=True)
def _penalty_pass(p, R, moved, fresh, t_obj, t_uv, t_w, colour, t_done, center, half_min, fx, fy, cx, cy, sig2,
                  dead_zone, use_pairs, half, pairs, tol, log_li, pair_flags, use_table, hull_all, hull_off, normal,
                  offset, lambda_h, table_tol, heights, out):
    """:meth:`PenaltyTerms.total` in one pass over the particles: recompute the colour rows of targets on ``moved``
    parts (or not yet computed, or all when ``fresh``), the intersection flags of pairs with a moved part and the
    lowest heights of moved parts, then sum ``−Σ colour + log λ_i [any pair intersects] + λ_h min(h_min + tol, 0)``
    in the order :func:`log_penalties` sums them."""
    n, k = p.shape[0], p.shape[1]
    for tt in range(t_obj.shape[0]):
        i = t_obj[tt]
        if not (fresh or moved[i] or not t_done[tt]):
            continue
        t_done[tt] = True
        c0, c1 = t_uv[tt, 0], t_uv[tt, 1]
        for j in range(n):
            x = R[j, i, 0, 0] * center[i, 0] + R[j, i, 0, 1] * center[i, 1] + R[j, i, 0, 2] * center[i, 2] + p[j, i, 0]
            y = R[j, i, 1, 0] * center[i, 0] + R[j, i, 1, 1] * center[i, 1] + R[j, i, 1, 2] * center[i, 2] + p[j, i, 1]
            z = R[j, i, 2, 0] * center[i, 0] + R[j, i, 2, 1] * center[i, 1] + R[j, i, 2, 2] * center[i, 2] + p[j, i, 2]
            z = max(z, 1e-3)
            du = fx * x / z + cx - c0
            dv = fy * y / z + cy - c1
            d2 = du * du + dv * dv
            if dead_zone > 0:
                r_in = dead_zone * half_min[i] * fx / z
                d2 = max(np.sqrt(d2) - r_in, 0.0)
                d2 = d2 * d2
            colour[tt, j] = 0.5 * t_w[tt] * min(d2, 9.0 * sig2) / sig2
    if use_pairs:
        m = pairs.shape[0]
        cnt = 0
        cols = np.empty(m, np.int64)
        for mm in range(m):
            if fresh or moved[pairs[mm, 0]] or moved[pairs[mm, 1]]:
                cols[cnt] = mm
                cnt += 1
        pair_intersections(R, p, center, half, pairs, cols[:cnt], tol, pair_flags)
    if use_table:
        for i in range(k):
            if not (fresh or moved[i]):
                continue
            h0, h1 = hull_off[i], hull_off[i + 1]
            for j in range(n):
                b0 = R[j, i, 0, 0] * normal[0] + R[j, i, 1, 0] * normal[1] + R[j, i, 2, 0] * normal[2]
                b1 = R[j, i, 0, 1] * normal[0] + R[j, i, 1, 1] * normal[1] + R[j, i, 2, 1] * normal[2]
                b2 = R[j, i, 0, 2] * normal[0] + R[j, i, 1, 2] * normal[1] + R[j, i, 2, 2] * normal[2]
                base = p[j, i, 0] * normal[0] + p[j, i, 1] * normal[1] + p[j, i, 2] * normal[2] + offset
                hmin = np.inf
                for v in range(h0, h1):
                    h = b0 * hull_all[v, 0] + b1 * hull_all[v, 1] + b2 * hull_all[v, 2] + base
                    if h < hmin or np.isnan(h):
                        hmin = h
                heights[j, i] = hmin
    for j in range(n):
        acc = 0.0
        for tt in range(t_obj.shape[0]):
            acc -= colour[tt, j]
        if use_pairs:
            hit = False
            for mm in range(pairs.shape[0]):
                if pair_flags[j, mm]:
                    hit = True
                    break
            acc += log_li if hit else 0.0
        if use_table:
            hm = np.inf
            for i in range(k):
                if heights[j, i] < hm or np.isnan(heights[j, i]):
                    hm = heights[j, i]
            acc += lambda_h * min(hm + table_tol, 0.0)
        out[j] = acc


@nb.njit(cache=True)
def pair_intersections(R, t, center, half, pairs, cols, tol, flags):
    """For the pairs ``pairs[cols]`` of parts: does the pair interpenetrate by more than ``tol`` metres, per particle,
    into ``flags[:, cols]`` ((N, M) bool); the test of :func:`tracker.filter.penalties.intersection_flags`."""
    rad = bounding_radii(half)
    cw = np.empty((R.shape[1], 3))
    for j in range(R.shape[0]):
        world_centres(R, t, j, center, cw)
        for mm in range(cols.shape[0]):
            m = cols[mm]
            a, b = pairs[m, 0], pairs[m, 1]
            # (the box test only for the pairs the spheres let through: see spheres_apart)
            flags[j, m] = not spheres_apart(cw, rad, a, b) and obb_overlap(R[j, a], cw[a], half[a], R[j, b], cw[b],
                                                                            half[b], tol)
