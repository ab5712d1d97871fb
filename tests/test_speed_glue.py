"""The coordinate passes' glue moved into kernels (session 32) gives the forms it replaced bit for bit (random, seeded
input): the propagation straight into a part's column, the likelihood's first call without the buffer fills, the
blob masks of the likelihood from a window of the grid."""

from __future__ import annotations

import math

import cv2
import numba as nb
import numpy as np
import pytest

from tracker.filter.depth_likelihood import _pixel_terms as pixel_terms
from tracker.filter.motion_model import propagate, propagate_part_into, rodrigues_terms, rotvec_to_matrix
from tracker.filter.penalties import bounding_radii, obb_overlap, world_centres
from tracker.geometry.fma import matmul33


def test_propagation_into_a_part_column_equals_gather_propagate_and_assign():
    """:func:`propagate_part_into` from last frame's rows ``perm`` writes exactly what gathering those rows,
    :func:`propagate` and assigning the part's column gave, and leaves the other columns alone."""
    rng = np.random.default_rng(5)
    n, k, obj = 60, 4, 2
    p_all = rng.normal(0.0, 0.3, (n, k, 3))
    R_all = np.stack([rotvec_to_matrix(rng.normal(0.0, 1.0, (n, 3))) for _ in range(k)], axis=1)
    v_all = rng.normal(0.0, 0.01, (n, k, 6))
    u = np.array([0.004, -0.002, 0.001])
    for perm in (np.arange(n), np.sort(rng.integers(0, n, n)), rng.permutation(n)):
        noise = rng.normal(0.0, 0.02, (n, 6))
        noise[:3, 3:] = 0.0  # no turn
        noise[3:6, 3:] = 1e-11  # below the series threshold
        p_out, R_out, v_out = (rng.normal(size=a.shape) for a in (p_all, R_all, v_all))
        want = [a.copy() for a in (p_out, R_out, v_out)]
        want[0][:, obj], want[1][:, obj], want[2][:, obj] = propagate(p_all[perm, obj], R_all[perm, obj],
                                                                      v_all[perm, obj], u, noise, 0.7, 0.4)
        propagate_part_into(p_all, R_all, v_all, perm.astype(np.int64), obj, noise, u, 0.7, 0.4, p_out, R_out, v_out)
        for got, ref in zip((p_out, R_out, v_out), want, strict=True):
            assert np.array_equal(got, ref)


def test_noisy_into_draws_and_moves_as_noisy():
    """:func:`tracker.filter.predict.noisy_into` takes the same noise draws as :func:`~tracker.filter.predict.noisy`
    (same generator state after) and gives its particles."""
    from types import SimpleNamespace

    from tracker.filter import predict
    from tracker.filter.tracker_config import TrackerConfig

    cfg = TrackerConfig.preset("default")
    rng = np.random.default_rng(2)
    n, k = 50, 3
    trk = SimpleNamespace(config=cfg, p=rng.normal(0.0, 0.3, (n, k, 3)),
                          R=np.stack([rotvec_to_matrix(rng.normal(0.0, 1.0, (n, 3))) for _ in range(k)], axis=1),
                          v=rng.normal(0.0, 0.01, (n, k, 6)), rng=np.random.default_rng(9))
    rows = np.sort(rng.integers(0, n, n)).astype(np.int64)
    u = np.array([0.01, 0.0, -0.003])
    want = predict.noisy(trk, trk.p[rows, 1], trk.R[rows, 1], trk.v[rows, 1], u, 1.7)
    after_want = trk.rng.random()
    trk.rng = np.random.default_rng(9)
    p_out, R_out, v_out = np.zeros((n, k, 3)), np.zeros((n, k, 3, 3)), np.zeros((n, k, 6))
    predict.noisy_into(trk, rows, 1, u, 1.7, p_out, R_out, v_out)
    assert trk.rng.random() == after_want
    for got, ref in zip((p_out[:, 1], R_out[:, 1], v_out[:, 1]), want, strict=True):
        assert np.array_equal(got, ref)
    assert not p_out[:, 0].any() and not p_out[:, 2].any()


def _likelihood_case(rng, n=40, k=3, p=70):
    """Inputs of :func:`update_log_likelihood` for a frame's first call: depth columns of k parts over p pixels (some
    uncovered: inf), dirty where a part was drawn, as the first render leaves them."""
    from tracker.filter.depth_likelihood import LikelihoodParams, pixel_constants

    prm = LikelihoodParams()
    loc = np.full((k, p), -1, np.int64)
    regions = rng.random((k, p)) < 0.6
    loc[regions] = np.arange(int(regions.sum()))
    m = int(regions.sum())
    z = rng.uniform(0.5, 1.2, p)
    D = np.where(rng.random((n, m)) < 0.5, z[np.nonzero(regions)[1]] + rng.normal(0.0, 0.01, (n, m)),
                 np.inf).astype(np.float32)
    D[1] = D[0]  # a copied particle: the memo takes the one before
    dirty = np.zeros((n, p), np.uint8)
    for o in range(k):
        cols = loc[o][regions[o]]
        dirty[:, np.flatnonzero(regions[o])] |= (D[:, cols] != np.inf).astype(np.uint8)
    s, e, lp = pixel_constants(z, prm)
    o_hat = rng.uniform(0.0, 0.6, (n, p)).astype(np.float32)
    cmask = (rng.random((k, p)) < 0.8).astype(np.uint8)
    cvalid = np.array([1, 0, 1][:k], np.uint8)
    return (D, loc, np.arange(p, dtype=np.int64), z, s, e, lp, o_hat, np.arange(n)), (
        prm.tail_weight, prm.occluder_rate, prm.tail_weight / prm.max_depth, True), dirty, cmask, cvalid


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fresh_likelihood_call_equals_the_call_on_filled_buffers(seed):
    """``fresh=True`` on buffers holding garbage gives the contributions, posteriors, front parts, log-likelihoods
    and cleared dirty flags of the call on buffers filled with 0 / −1 / −1 first (the fills it replaces)."""
    from tracker.filter.depth_likelihood import update_log_likelihood

    rng = np.random.default_rng(seed)
    head, consts, dirty, cmask, cvalid = _likelihood_case(rng)
    n, p = dirty.shape
    outs = []
    for fresh in (False, True):
        if fresh:
            C = rng.normal(size=(n, p)).astype(np.float32)
            Q = rng.normal(size=(n, p)).astype(np.float32)
            F = rng.integers(-5, 5, (n, p)).astype(np.int8)
        else:
            C, Q, F = np.zeros((n, p), np.float32), np.full((n, p), -1.0, np.float32), np.full((n, p), -1, np.int8)
        ell = np.zeros(n)
        dd = dirty.copy()
        update_log_likelihood(*head, C, Q, F, ell, *consts, dd, 1.0, cmask, cvalid, 2.0, fresh)
        outs.append((C, Q, F, ell, dd))
    assert (outs[0][3] != 0).any()  # something was covered
    for a, b in zip(*outs, strict=True):
        assert np.array_equal(a, b)


def _blob_pixels_reference(poly, grid, gi, gj):
    """The form :func:`tracker.filter.colour_input.grid_blob_pixels` replaced: the whole grid filled and dilated."""
    m = np.zeros(grid, np.uint8)
    cv2.fillPoly(m, [poly], 1)
    m = cv2.dilate(m, np.ones((3, 3), np.uint8))
    return m[gj, gi]


def test_windowed_blob_pixels_equal_the_whole_grid_fill_and_dilation():
    """Polygons inside, across every edge of and wholly outside the grid, convex and not, large and of a pixel:
    the windowed fill and the 3 × 3 maximum at the listed pixels give the whole grid's values at every pixel."""
    from tracker.filter.colour_input import grid_blob_pixels

    rng = np.random.default_rng(11)
    grid = (60, 80)
    gj, gi = (a.ravel().astype(np.int64) for a in np.meshgrid(np.arange(grid[0]), np.arange(grid[1]), indexing="ij"))
    sel = rng.permutation(gi.size)[:1500]  # a subset of pixels in any order, as the evaluated pixels come
    polys = [np.array([[10, 10], [30, 12], [25, 40]]), np.array([[0, 0], [0, 0], [0, 0]]),
             np.array([[79, 59], [79, 59], [78, 59]]), np.array([[-20, -5], [15, 3], [2, 30]]),
             np.array([[70, 50], [120, 55], [90, 90]]), np.array([[-30, -30], [-10, -20], [-15, -5]]),
             np.array([[100, 10], [130, 12], [110, 40]]), np.array([[-10, 30], [95, 28], [40, 70]])]
    for _ in range(300):  # random polygons, many not convex, some far beyond the grid
        c = rng.uniform(-30, 110, 2)
        nv = int(rng.integers(3, 12))
        ang = np.sort(rng.uniform(0, 2 * np.pi, nv))
        r = rng.uniform(0.5, 40.0) * rng.uniform(0.3, 1.0, nv)
        polys.append(np.stack([c[0] + r * np.cos(ang), c[1] + r * np.sin(ang)], axis=1))
        polys.append(rng.uniform(-20, 100, (nv, 2)))  # self-intersecting
    n_hit = 0
    for poly in polys:
        poly = np.round(poly).astype(np.int32)
        for g_i, g_j in ((gi, gj), (gi[sel], gj[sel])):
            out = np.full(g_i.size, 7, np.uint8)
            grid_blob_pixels(poly, grid, g_i, g_j, out)
            want = _blob_pixels_reference(poly, grid, g_i, g_j)
            assert np.array_equal(out, want), poly
            n_hit += int(want.any())
    assert n_hit > 200  # most polygons reach the grid


def test_systematic_resampling_kernel_matches_numpy():
    """The kernel's indices equal the numpy form's (cumulative sums, searchsorted) for the same draw, on weights
    normalised or not, with zeros, one dominant particle, ties and every size up to past numpy's pairwise block; the
    generator advances alike; weights summing to zero or not finite are refused."""
    from tracker.filter.resampling import systematic_resample, systematic_resample_numpy

    rng = np.random.default_rng(4)
    n_cases = 0
    for n in (1, 2, 3, 7, 8, 9, 127, 128, 129, 225, 1000):
        for kind in range(6):
            w = rng.random(n)
            if kind == 1:
                w /= w.sum()
            elif kind == 2:
                w[rng.random(n) < 0.7] = 0.0
                w[0] = max(w[0], 1e-3)
            elif kind == 3:
                w = np.full(n, 1e-300)
                w[n // 2] = 1.0
            elif kind == 4:
                w = np.full(n, 0.1)  # ties everywhere: running sums just above and below the keys
            elif kind == 5:
                w = np.exp(rng.normal(0.0, 30.0, n))  # as the weights come: exp of log-likelihoods, wide range
            seed = int(rng.integers(1 << 30))
            r1, r2 = np.random.default_rng(seed), np.random.default_rng(seed)
            got = systematic_resample(w, r1)
            want = systematic_resample_numpy(w, r2)
            assert got.dtype == want.dtype == np.int64
            assert np.array_equal(got, want), (n, kind)
            assert r1.random() == r2.random()
            n_cases += 1
    assert n_cases == 66
    for bad in (np.zeros(5), np.array([1.0, np.nan]), np.array([np.inf, 1.0]), np.zeros(0)):
        with pytest.raises(ValueError):
            systematic_resample(bad, np.random.default_rng(0))


# main 692b04e's update_log_likelihood, which scanned every (particle, subset pixel) flag: the reference of the form
# that compacts each particle's dirty positions first (the same pixels in the same order)
@nb.njit(cache=True)
def _flag_scan_likelihood(D, loc, subset, z, s, e, log_po_inf, o_hat, anc, C, Q, F, ell, beta, lam, tail, use_occ,
                          dirty, alpha, cmask, cvalid, occ_cap=0.0, fresh=False):
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
    for j in range(n):
        acc = 0.0
        for ii in range(m):
            i = subset[ii]
            if dirty[j, i] == 0:
                if fresh:
                    C[j, i] = 0.0
                    Q[j, i] = -1.0
                    F[j, i] = -1
                continue
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
                    lik, num = pixel_terms(d, z[i], s[i], e[i], oh, beta, lam, tail, True if oh == 1.0 else use_occ)
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



@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_compacted_likelihood_equals_the_flag_scan(seed):
    """A pass's call (not ``fresh``) on a subset, after some particles' depths changed (dirty flags at 0-60 % of the
    pixels, copies of the particle before, a permuted ancestry), gives the contributions, posteriors, front parts,
    log-likelihoods and cleared flags of the flag-scanning form, over three passes in a row; the first call too."""
    from tracker.filter.depth_likelihood import update_log_likelihood

    rng = np.random.default_rng(seed)
    head, consts, dirty, cmask, cvalid = _likelihood_case(rng, n=50, k=3, p=90)
    D, loc, all_pix, z, s, e, lp, o_hat, anc = head
    n, p = dirty.shape
    arms = []
    for fn in (_flag_scan_likelihood, update_log_likelihood):
        arms.append([D.copy(), np.zeros((n, p), np.float32), np.full((n, p), -1.0, np.float32),
                     np.full((n, p), -1, np.int8), np.zeros(n), dirty.copy(), fn])
    for a in arms:
        Da, C, Q, F, ell, dd, fn = a
        fn(Da, loc, all_pix, z, s, e, lp, o_hat, anc, C, Q, F, ell, *consts, dd, 1.0, cmask, cvalid, 2.0, True)
    anc2 = rng.permutation(n)
    for _ in range(3):
        subset = np.flatnonzero(rng.random(p) < 0.7).astype(np.int64)
        frac = rng.uniform(0.0, 0.6)
        change = rng.random(D.shape) < frac
        new = np.where(rng.random(D.shape) < 0.7, D + rng.normal(0.0, 0.005, D.shape).astype(np.float32),
                       np.inf).astype(np.float32)
        new[3] = new[2]  # a copy: the memo's case
        flags = np.zeros((n, p), np.uint8)
        for o in range(loc.shape[0]):
            for i in subset:
                col = loc[o, i]
                if col >= 0:
                    flags[:, i] |= change[:, col].astype(np.uint8)
        for a in arms:
            Da, C, Q, F, ell, dd, fn = a
            Da[change] = new[change]
            dd |= flags
            fn(Da, loc, subset, z, s, e, lp, o_hat, anc2, C, Q, F, ell, *consts, dd, 1.0, cmask, cvalid, 2.0, False)
    assert np.abs(arms[0][4]).max() > 0
    for x, y in zip(arms[0][:6], arms[1][:6], strict=True):
        assert np.array_equal(x, y)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_body_points_equal_the_numpy_transform_of_the_camera_points(seed):
    """``SurfaceRender.body_points_of`` gives ``(pts − t) @ R`` and ``nrm @ R`` of ``points_of`` bit for bit (numpy's
    BLAS rounding of these shapes) for parts of 0 to some thousand points, rotations and arbitrary matrices."""
    from tracker.filter.motion_model import rotvec_to_matrix as rv
    from tracker.geometry.camera import Intrinsics
    from tracker.refine.surface_render import render_surfaces

    rng = np.random.default_rng(seed)
    intr = Intrinsics(640, 480, 600.0, 600.0, 320.0, 240.0)
    shapes = [("box", np.zeros(3), np.array([0.02, 0.025, 0.03])), ("box", np.zeros(3), np.array([0.05, 0.01, 0.02])),
              ("box", np.zeros(3), np.array([0.003, 0.003, 0.003]))]
    n_seen = 0
    for _ in range(20):
        poses = [(rv(rng.normal(0.0, 1.0, (1, 3)))[0], np.array([rng.uniform(-0.15, 0.15), rng.uniform(-0.1, 0.1),
                                                                  rng.uniform(0.2, 0.9)])) for _ in shapes]
        render = render_surfaces(intr, shapes, poses, (0, 0, 640, 480), int(rng.integers(1, 4)))
        for obj in range(-1, len(shapes) + 1):
            R = poses[obj][0] if 0 <= obj < len(shapes) and rng.random() < 0.7 else rng.normal(0.0, 1.0, (3, 3))
            t = rng.normal(0.0, 0.5, 3)
            pts, nrm = render.points_of(obj, intr)
            body, nbody = render.body_points_of(obj, intr, R, t)
            assert body.shape == pts.shape and nbody.shape == nrm.shape
            assert np.array_equal(body, (pts - t) @ R) and np.array_equal(nbody, nrm @ R)
            n_seen += pts.shape[0]
    assert n_seen > 1000


@nb.njit(cache=True)
def _nearest_grid_order(pts, lo, dims, start, order, cell, bound2, q0, q1, q2):
    """The hand registration's nearest-point search as it was before session 34: the 27 cells around the query in
    grid order, the first strictly nearer point kept (the reference of :func:`point_icp._nearest`)."""
    fx = np.floor((q0 - lo[0]) / cell)
    fy = np.floor((q1 - lo[1]) / cell)
    fz = np.floor((q2 - lo[2]) / cell)
    best, best_d2 = -1, bound2
    if fx < -1.0 or fy < -1.0 or fz < -1.0 or fx > dims[0] or fy > dims[1] or fz > dims[2]:
        return best, best_d2
    ix, iy, iz = int(fx), int(fy), int(fz)
    for ax in range(max(ix - 1, 0), min(ix + 2, dims[0])):
        for ay in range(max(iy - 1, 0), min(iy + 2, dims[1])):
            base = (ax * dims[1] + ay) * dims[2]
            for az in range(max(iz - 1, 0), min(iz + 2, dims[2])):
                k = base + az
                for s in range(start[k], start[k + 1]):
                    j = order[s]
                    dx = q0 - pts[j, 0]
                    dy = q1 - pts[j, 1]
                    dz = q2 - pts[j, 2]
                    d2 = dx * dx + dy * dy + dz * dz
                    if d2 < best_d2:
                        best, best_d2 = j, d2
    return best, best_d2


@pytest.mark.parametrize("seed", range(4))
def test_pruned_nearest_search_equals_the_grid_order_scan(seed):
    """:func:`point_icp._nearest` (own cell first, neighbour cells skipped beyond the best, a seed tried first)
    finds exactly the point and squared distance of the 27-cell scan in grid order, ties included: clouds, noisy
    surfaces and lattices (many equal distances, points on cell walls), duplicated points, queries inside, on the
    lattice and just outside the grid, seeds none, the true answer, near and anywhere."""
    from tracker.geometry.point_icp import _nearest, build_grid

    rng = np.random.default_rng(40 + seed)
    n_seeded = n_ties = 0
    for case in range(12):
        kind = case % 3
        cell = 0.02
        if kind == 0:  # a cloud
            pts = rng.uniform(-0.08, 0.08, (int(rng.integers(20, 700)), 3))
        elif kind == 1:  # a noisy curved surface, as a hand's points
            uv = rng.uniform(-0.1, 0.1, (int(rng.integers(50, 900)), 2))
            pts = np.column_stack([uv, 0.3 * (uv**2).sum(1) + rng.normal(0.0, 5e-4, uv.shape[0])])
        else:  # a lattice of a quarter cell: walls and equal distances
            pts = rng.integers(-12, 12, (int(rng.integers(20, 600)), 3)) * (cell / 4.0)
        pts = pts + rng.uniform(-1.0, 1.0, 3)
        pts = np.vstack([pts, pts[rng.integers(0, pts.shape[0], pts.shape[0] // 10)]])  # duplicates
        pts = np.ascontiguousarray(pts[rng.permutation(pts.shape[0])])
        lo, dims, start, order = build_grid(pts, cell)
        spts = np.ascontiguousarray(pts[order])
        inv = np.empty_like(order)
        inv[order] = np.arange(order.size)
        bound2 = (cell * (1.0 if case % 2 else 0.7)) ** 2
        span = pts.max(0) - pts.min(0)
        for _ in range(400):
            r = rng.random()
            if r < 0.4:  # near a point
                q = pts[rng.integers(0, pts.shape[0])] + rng.normal(0.0, 0.004, 3)
            elif r < 0.6:  # on the lattice of the points' walls
                q = lo + rng.integers(-1, 12, 3) * (cell / 4.0)
            elif r < 0.8:  # a point itself
                q = pts[rng.integers(0, pts.shape[0])].copy()
            else:  # anywhere around the grid, inside or up to two cells out
                q = lo + rng.uniform(-2.0 * cell, 1.0, 3) * np.maximum(span, 1e-6) + rng.uniform(-0.03, 0.03, 3)
            want, want_d2 = _nearest_grid_order(pts, lo, dims, start, order, cell, bound2, q[0], q[1], q[2])
            seeds = [-1, int(rng.integers(0, pts.shape[0]))]
            if want >= 0:
                seeds.append(int(inv[want]))
                d = ((pts - q) ** 2).sum(1)
                n_ties += int((d == want_d2).sum() > 1)
            for s0 in seeds:
                got, got_d2, got_s = _nearest(spts, lo, dims, start, order, cell, bound2, q[0], q[1], q[2], s0)
                assert (got, got_d2) == (want, want_d2), (case, q, s0)
                assert got_s == (inv[got] if got >= 0 else -1)
                n_seeded += s0 >= 0
    assert n_seeded > 5000
    assert n_ties > 20  # equal distances did occur (the lattices, the duplicates)


@nb.njit(cache=True)
def _pair_flags_reference(R, t, center, half, pairs, cols, tol, flags):
    """The pair test as one function before session 34 (bounding spheres, then the boxes' separating axes) for the
    pairs ``pairs[cols]`` of every particle (the reference of the penalties' pair kernels)."""
    rad = bounding_radii(half)
    cw = np.empty((R.shape[1], 3))
    for j in range(R.shape[0]):
        world_centres(R, t, j, center, cw)
        for mm in range(cols.shape[0]):
            m = cols[mm]
            a, b = pairs[m, 0], pairs[m, 1]
            d2 = (cw[a, 0] - cw[b, 0]) ** 2 + (cw[a, 1] - cw[b, 1]) ** 2 + (cw[a, 2] - cw[b, 2]) ** 2
            if d2 > (rad[a] + rad[b]) ** 2:
                flags[j, m] = False
            else:
                flags[j, m] = obb_overlap(R[j, a], cw[a], half[a], R[j, b], cw[b], half[b], tol)


@pytest.mark.parametrize("seed", range(3))
def test_pair_kernels_equal_the_sphere_then_boxes_test(seed):
    """The coordinate passes' pair flags (:func:`weigh.pair_intersections`) and the refinement's per-particle test
    (:func:`penalties.intersection_flags`), with the sphere test and the box test written apart, give the flags of
    the one-function form on boxes apart, touching, crossing and nested (every kind occurs)."""
    from tracker.filter.penalties import intersection_flags
    from tracker.filter.weigh import pair_intersections

    rng = np.random.default_rng(70 + seed)
    n, k = 300, 5
    half = rng.uniform(0.01, 0.04, (k, 3))
    center = rng.normal(0.0, 0.005, (k, 3))
    pairs = np.array([(a, b) for a in range(k) for b in range(a + 1, k)], np.int64)
    spread = np.array([0.01, 0.03, 0.08, 0.3])[rng.integers(0, 4, n)]  # nested to far apart
    t = rng.normal(0.0, 1.0, (n, k, 3)) * spread[:, None, None] + np.array([0.0, 0.0, 0.6])
    R = np.stack([rotvec_to_matrix(rng.normal(0.0, 1.0, (n, 3))) for _ in range(k)], axis=1)
    R[: n // 4] = np.eye(3)  # aligned boxes: the cross-product axes degenerate
    for tol in (0.0, 0.002):
        for cols in (np.arange(len(pairs), dtype=np.int64), np.array([1, 4, 7], np.int64)):
            want = np.zeros((n, len(pairs)), np.bool_)
            got = np.ones((n, len(pairs)), np.bool_)
            _pair_flags_reference(R, t, center, half, pairs, cols, tol, want)
            got[:, np.setdiff1d(np.arange(len(pairs)), cols)] = False
            pair_intersections(R, t, center, half, pairs, cols, tol, got)
            assert np.array_equal(got, want)
        every = np.zeros((n, len(pairs)), np.bool_)
        _pair_flags_reference(R, t, center, half, pairs, np.arange(len(pairs), dtype=np.int64), tol, every)
        assert np.array_equal(intersection_flags(R, t, center, half, pairs, tol), every.any(axis=1))
        assert 0.1 < every.any(axis=1).mean() < 0.9  # some particles with a crossing pair, some without


@nb.njit(cache=True)
def _propagate_by_views(p_all, R_all, v_all, rows, obj, noise, u, k_v, b, p_out, R_out, v_out):
    """The propagation kernel as it was before session 34 (one inlined step per particle on views of its rows; the
    reference of :func:`propagate_part_into`)."""
    K = np.empty((3, 3))
    KK = np.empty((3, 3))
    E = np.empty((3, 3))
    for j in range(rows.shape[0]):
        r = rows[j]
        v_prev, p_ref, R_ref = v_all[r, obj], p_all[r, obj], R_all[r, obj]
        v, p, R = v_out[j, obj], p_out[j, obj], R_out[j, obj]
        for a in range(6):
            v[a] = k_v * v_prev[a] + noise[j, a]
        for a in range(3):
            v[a] += b * u[a]
            p[a] = p_ref[a] + v[a]
        fa, fb = rodrigues_terms(v[3], v[4], v[5], K)
        matmul33(K, K, KK)
        for a in range(3):
            for c in range(3):
                eye = 1.0 if a == c else 0.0
                E[a, c] = (eye + fa * K[a, c]) + fb * KK[a, c]
        matmul33(E, R_ref, R)


def test_propagation_by_index_equals_the_kernel_on_views():
    """:func:`propagate_part_into` (entries read and written by index) and :func:`propagate` (the same kernel on a
    part's column) give the view-based kernel's particles bit for bit: ordered, repeated and permuted rows, turns
    below the series threshold, small and large."""
    rng = np.random.default_rng(11)
    n, k, obj = 90, 4, 1
    p_all = rng.normal(0.0, 0.3, (n, k, 3))
    R_all = np.stack([rotvec_to_matrix(rng.normal(0.0, 1.0, (n, 3))) for _ in range(k)], axis=1)
    u = np.array([0.004, -0.002, 0.001])
    for scale in (1e-10, 1e-3, 0.05, 1.5):
        v_all = rng.normal(0.0, scale, (n, k, 6))
        for perm in (np.arange(n), np.sort(rng.integers(0, n, n)), rng.permutation(n)):
            noise = rng.normal(0.0, scale, (n, 6))
            noise[:4, 3:] = -v_all[perm[:4], obj, 3:] * 0.7  # no turn at all
            outs = [tuple(rng.normal(size=a.shape) for a in (p_all, R_all, v_all)) for _ in range(2)]
            outs[1] = tuple(a.copy() for a in outs[0])
            propagate_part_into(p_all, R_all, v_all, perm.astype(np.int64), obj, noise, u, 0.7, 0.4, *outs[0])
            _propagate_by_views(p_all, R_all, v_all, perm.astype(np.int64), obj, noise, u, 0.7, 0.4, *outs[1])
            for got, want in zip(*outs, strict=True):
                assert np.array_equal(got, want)
            p, R, v = propagate(p_all[perm, obj], R_all[perm, obj], v_all[perm, obj], u, noise, 0.7, 0.4)
            assert np.array_equal(p, outs[1][0][:, obj])
            assert np.array_equal(R, outs[1][1][:, obj])
            assert np.array_equal(v, outs[1][2][:, obj])
