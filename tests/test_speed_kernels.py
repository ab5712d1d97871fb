"""Numba kernels that replaced numpy code for speed give the numpy reference's results (random, seeded input)."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.filter import render
from tracker.filter.motion_model import rotvec_to_matrix
from tracker.filter.particle_filter import MultiObjectTracker
from tracker.filter.tracker_config import TrackerConfig
from tracker.geometry.camera import Intrinsics
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose

INTR = Intrinsics(640, 480, 600.0, 600.0, 320.0, 240.0)


def evaluated_pixels_reference(trk, depth, p_prev, R_prev, p_det, R_det):
    """The numpy form of :func:`tracker.filter.render.evaluated_pixels` (before its per-pixel work moved to numba)."""
    cfg = trk.config
    intr = trk.intrinsics
    z = depth[np.ix_(trk._vs, trk._us)].reshape(-1)
    valid = np.isfinite(z) & (z > 0) & (z < cfg.max_depth)
    if not valid.any():
        return None
    k = len(trk.parts)
    regions = np.zeros((k, z.size), bool)
    f = cfg.wide_noise_fraction
    spread = np.sqrt((1.0 - f) + f * cfg.wide_noise_scale**2)
    for i in range(k):
        rect = render.union(render.bbox(trk, i, p_prev[:, i], R_prev[:, i]),
                            render.bbox(trk, i, p_det[:, i], R_det[:, i]))
        zc = max(float(np.median(p_det[:, i, 2])), 0.05)
        radius = float(np.linalg.norm(trk.half[i]) + np.linalg.norm(trk.center[i]))
        scale = spread * trk._noise_scale[i]
        margin = (cfg.roi_margin_px * cfg.downsample
                  + 3.0 * scale * (cfg.sigma_v + cfg.sigma_w * radius) * intr.fx / zc)
        regions[i] = ((trk._pu >= rect[0] - margin) & (trk._pu <= rect[1] + margin)
                      & (trk._pv >= rect[2] - margin) & (trk._pv <= rect[3] + margin))
    budget = cfg.likelihood_pixels_per_part
    lattice = trk._lattice.copy()
    if budget > 0:
        keep = np.zeros(z.size, bool)
        for i in range(k):
            sel = regions[i] & valid
            count = int(np.count_nonzero(sel))
            c = max(int(np.ceil(np.sqrt(count / budget))), 1) if count > budget else 1
            if c > 1:
                sel &= (trk._gi % c == 0) & (trk._gj % c == 0)
            lattice[i] = c
            keep |= sel
    else:
        keep = regions.any(axis=0) & valid
    pix = np.nonzero(keep)[0].astype(np.int64)
    if not pix.size:
        return None
    return pix, regions[:, pix], lattice


@pytest.mark.parametrize("budget", [0, 40, 250])
def test_evaluated_pixels_match_the_numpy_reference(budget):
    rng = np.random.default_rng(11)
    parts = [PartSpec.cube(c, c) for c in ("red", "green", "blue")]
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=30, likelihood_pixels_per_part=budget)
    trk = MultiObjectTracker(parts, INTR, cfg, seed=0)
    poses = {p.name: Pose.from_rt(np.eye(3), np.array([x, 0.02, 0.45])) for p, x in zip(parts, (-0.08, 0.0, 0.07),
                                                                                       strict=True)}
    trk.initialize(poses)
    for trial in range(6):
        n, k = 30, len(parts)
        p_prev = trk.p + rng.normal(0.0, 0.01, (n, k, 3))
        R_prev = np.stack([rotvec_to_matrix(rng.normal(0.0, 0.3, (n, 3))) for _ in range(k)], axis=1)
        p_det = p_prev + rng.normal(0.0, 0.005, (n, k, 3))
        R_det = R_prev
        trk._noise_scale = rng.uniform(0.3, 1.0, k)
        depth = rng.uniform(0.2, 7.0, (INTR.height, INTR.width)).astype(np.float32)
        depth[rng.random(depth.shape) < 0.2] = np.nan
        depth[rng.random(depth.shape) < 0.05] = 0.0
        if trial == 5:
            depth[:] = np.nan  # no valid depth anywhere: None, and the lattice is left alone
        want = evaluated_pixels_reference(trk, depth, p_prev, R_prev, p_det, R_det)
        before = trk._lattice.copy()
        got = render.evaluated_pixels(trk, depth, p_prev, R_prev, p_det, R_det)
        if want is None:
            assert got is None
            assert np.array_equal(trk._lattice, before)
            continue
        assert got is not None
        assert np.array_equal(got[0], want[0])
        assert np.array_equal(got[1], want[1])
        assert np.array_equal(trk._lattice, want[2])
        assert got[0].size > 0
        if budget == 40:
            assert trk._lattice.max() > 1  # the thinning to a coarser lattice is exercised


@pytest.mark.parametrize("budget", [0, 30])
def test_evaluated_pixel_kernel_visits_only_the_rectangles(budget):
    """The rectangles' rows and columns alone give the selection of the whole-grid test (numpy over every grid pixel):
    unbounded, empty, NaN, off-image and overlapping rectangles, with and without a budget."""
    rng = np.random.default_rng(13)
    trk = MultiObjectTracker([PartSpec.cube("red", "red")], INTR, TrackerConfig.preset("default"), seed=0)
    us, vs, pu, pv, gi, gj = trk._us, trk._vs, trk._pu, trk._pv, trk._gi, trk._gj
    depth = rng.uniform(0.2, 7.0, (INTR.height, INTR.width)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.3] = np.nan
    inf, nan = np.inf, np.nan
    bounds = np.array([[100.0, 260.5, 40.0, 200.0], [-inf, inf, -inf, inf], [inf, -inf, inf, -inf],
                       [nan, 300.0, 0.0, 100.0], [600.0, 900.0, -50.0, 30.0], [150.0, 400.0, 120.0, 470.0]])
    k = bounds.shape[0]
    budgets = np.full(k, budget, np.int64)
    lattice = np.ones(k, np.int64)
    pix, regions, any_valid = render._evaluated(depth, vs, us, 6.0, pu, pv, gi, gj, bounds, budgets, lattice)
    z = depth[np.ix_(vs, us)].reshape(-1)
    valid = np.isfinite(z) & (z > 0) & (z < 6.0)
    inside = np.array([(pu >= b[0]) & (pu <= b[1]) & (pv >= b[2]) & (pv <= b[3]) for b in bounds])
    keep = np.zeros(pu.size, bool)
    for i in range(k):
        sel = inside[i] & valid
        count = int(sel.sum())
        c = max(int(np.ceil(np.sqrt(count / budget))), 1) if budget > 0 and count > budget else 1
        if budget > 0:
            assert lattice[i] == c
        keep |= sel & ((gi % c == 0) & (gj % c == 0) if c > 1 else True)
    assert any_valid
    assert np.array_equal(pix, np.flatnonzero(keep)) and np.array_equal(regions, inside[:, keep])
    assert not inside[2].any() and not inside[3].any() and inside[1].all()


def test_surface_points_of_a_part_come_from_its_own_rows_and_columns():
    """A part's visible surface points, taken from the rows and columns its labels span, equal those of the scan of the
    whole strided render (every cell labelled with it, row-major, back-projected with numpy), for parts hiding each
    other, a part off the render and a label no part has."""
    from tracker.refine.surface_render import render_surfaces

    rng = np.random.default_rng(14)
    shapes = [("box", np.zeros(3), np.array([0.02, 0.025, 0.02])) for _ in range(4)]
    poses = [(rotvec_to_matrix(rng.normal(0.0, 0.5, (1, 3)))[0], np.array([x, y, z]))
             for x, y, z in ((-0.03, 0.0, 0.40), (0.0, 0.01, 0.43), (0.05, -0.02, 0.5), (2.0, 0.0, 0.5))]
    render = render_surfaces(INTR, shapes, poses, (150, 120, 500, 380), 2)
    assert len({int(v) for v in np.unique(render.label)} - {-1}) == 3  # the fourth part lies off the render
    for obj in range(6):
        jj, ii = np.nonzero(render.label == obj)
        u = (render.u0 + ii * render.stride).astype(np.float64)
        v = (render.v0 + jj * render.stride).astype(np.float64)
        z = render.depth[jj, ii]
        want = np.stack([(u - INTR.cx) / INTR.fx * z, (v - INTR.cy) / INTR.fy * z, z], axis=1).reshape(-1, 3)
        pts, nrm = render.points_of(obj, INTR)
        assert np.array_equal(pts, want) and np.array_equal(nrm, render.normal[jj, ii].reshape(-1, 3))
        assert (pts.shape[0] > 100) == (obj < 3)


@pytest.mark.parametrize("p10,p11", [(0.1, 0.8), (0.2, 0.2), (0.0, 1.0)])
def test_predicted_occlusion_matches_the_numpy_reference(p10, p11):
    """ô of the coordinate passes (numba, transposed, with a hand's occluder prior as a floor) equals the numpy form:
    ``np.maximum(predict_occlusion_rows(occ[pix], Δt, …).T, prior)``."""
    from tracker.filter.depth_likelihood import occlusion_affine, predict_occlusion_rows, predicted_occlusion

    rng = np.random.default_rng(2)
    occ = rng.random((500, 40)).astype(np.float32)
    pix = np.sort(rng.choice(500, 120, replace=False)).astype(np.int64)
    dt = np.where(rng.random(120) < 0.2, 0.0, rng.uniform(0.01, 0.5, 120))
    ab = occlusion_affine(dt, p10, p11)
    a, b = ab if ab is not None else (np.ones(120, np.float32), np.zeros(120, np.float32))
    want = np.ascontiguousarray(predict_occlusion_rows(occ[pix], dt, p10, p11).T)
    got = predicted_occlusion(occ, pix, a, b, np.full(120, -np.inf, np.float32))
    assert got.dtype == np.float32 and np.array_equal(got, want)
    prior = np.where(rng.random(120) < 0.3, np.float32(0.9) * rng.random(120).astype(np.float32), np.float32(0.0))
    got = predicted_occlusion(occ, pix, a, b, prior.astype(np.float32))
    assert np.array_equal(got, np.maximum(want, prior.astype(np.float32)[None, :]))


def test_occlusion_posterior_goes_straight_into_the_stored_rows():
    """:func:`finish_occlusion_into` writes what the (N, P) posterior and its transposed scatter
    ``occ[pix] = post.T`` wrote (ô of the particle's ancestor where nothing covers the pixel, else the cached
    posterior), leaves the other grid rows alone, and returns the same visible fractions."""
    from tracker.filter.depth_likelihood import finish_occlusion_into

    rng = np.random.default_rng(11)
    n, p, k, grid = 30, 80, 4, 300
    Q = np.where(rng.random((n, p)) < 0.4, np.float32(-1.0), rng.random((n, p)).astype(np.float32))
    F = np.where(Q < 0, -1, rng.integers(0, k - 1, (n, p))).astype(np.int8)  # part k - 1 is front-most nowhere
    o_hat = rng.random((n, p)).astype(np.float32)
    anc = np.sort(rng.integers(0, n, n)).astype(np.int64)
    pix = np.sort(rng.choice(grid, p, replace=False)).astype(np.int64)
    occ = rng.random((grid, n)).astype(np.float32)
    # the replaced form: the posterior (N, P), then numpy's scatter; the visible fractions by their definition
    post = np.where(Q < 0, o_hat[anc], Q)
    want = occ.copy()
    want[pix] = post.T
    vis_want = np.zeros((n, k))
    for j in range(n):
        for o in range(k):
            sel = F[j] == o
            vis_want[j, o] = np.sum(1.0 - Q[j, sel].astype(np.float64)) / sel.sum() if sel.any() else 0.0
    got = occ.copy()
    vis = finish_occlusion_into(Q, F, o_hat, anc, k, got, pix)
    assert np.array_equal(got, want)
    assert np.allclose(vis, vis_want, rtol=1e-12, atol=0) and np.all(vis[:, k - 1] == 0.0)


def _close_to_ulps(got: np.ndarray, want: np.ndarray, scale: np.ndarray | None = None, ulps: float = 8.0) -> bool:
    """Whether ``got`` equals ``want`` to within ``ulps`` machine epsilons of ``scale`` (default: the larger of the
    two magnitudes; for a sum of products, the sum of their magnitudes, which bounds its rounding error). The numba
    kernels below round as numpy does on the machine they were written on (AMD EPYC, OpenBLAS's kernel for it: bit for
    bit there); numpy's matmul and einsum pick their kernels by CPU, and another CPU's kernel may sum a product in
    another order, so the tests allow a few roundings."""
    if scale is None:
        scale = np.maximum(np.abs(want), np.abs(got))
    return bool(np.all(np.abs(got - want) <= ulps * np.finfo(float).eps * scale))


def test_fused_3x3_product_rounds_as_numpy_matmul():
    """matmul33 (one fused multiply-add chain per entry, in a numba kernel) gives numpy's stacked 3×3 matmul (bit for
    bit on the development machine; within a few ulps of any CPU's, :func:`_close_to_ulps`), on contiguous and
    strided stacks of widely scaled entries; fma rounds once."""
    import numba as nb

    from tracker.geometry.fma import fma, matmul33

    @nb.njit
    def stack_product(A, B, fused):
        out = np.empty((A.shape[0], 3, 3))
        for j in range(A.shape[0]):
            if fused:
                matmul33(A[j], B[j], out[j])
            else:
                for a in range(3):
                    for c in range(3):
                        out[j, a, c] = A[j, a, 0] * B[j, 0, c] + A[j, a, 1] * B[j, 1, c] + A[j, a, 2] * B[j, 2, c]
        return out

    rng = np.random.default_rng(5)
    A = rng.normal(size=(4000, 3, 3)) * 10.0 ** rng.uniform(-6, 2, (4000, 1, 1))
    B = rng.normal(size=(4000, 4, 3, 3))[:, 2]  # a strided slice, as one part of the (N, K, 3, 3) particles
    bound = np.abs(A) @ np.abs(B)  # a dot product's rounding error is a few eps of the sum of its terms' magnitudes
    assert _close_to_ulps(stack_product(A, B, True), A @ B, bound)
    assert _close_to_ulps(stack_product(A, B, False), A @ B, bound)  # the plain sum: the same product

    @nb.njit
    def one(x, y, z):
        return fma(x, y, z)

    assert one(1.0 + 2.0**-30, 1.0 - 2.0**-30, -1.0) == -(2.0**-60)  # one rounding: the exact product's tail kept


def test_propagate_kernel_matches_numpy():
    """The propagation in one numba kernel gives the numpy computation's particles (bit for bit on the development
    machine, :func:`_close_to_ulps`), on strided per-part slices as the coordinate passes hand it, for small and
    large turns and for rotations below the series threshold."""
    from tracker.filter.motion_model import propagate, propagate_numpy

    rng = np.random.default_rng(3)
    n, k = 80, 3
    p = rng.normal(0.0, 0.3, (n, k, 3))
    R = np.stack([rotvec_to_matrix(rng.normal(0.0, 1.0, (n, 3))) for _ in range(k)], axis=1)
    u = np.array([0.01, -0.02, 0.003])
    for scale in (1e-4, 1e-2, 0.3, 2.0):
        v = rng.normal(0.0, scale, (n, k, 6))
        noise = rng.normal(0.0, scale, (n, 6))
        v[:6, 1, 3:] = 0.0
        noise[:3, 3:] = 0.0  # no rotation at all
        noise[3:6, 3:] = 1e-11  # below the series threshold
        got = propagate(p[:, 1], R[:, 1], v[:, 1], u, noise, 0.8, 0.3)
        want = propagate_numpy(p[:, 1], R[:, 1], v[:, 1], u, noise.copy(), 0.8, 0.3)
        for a, b in zip(got, want, strict=True):
            assert a.shape == b.shape
            assert np.allclose(a, b, rtol=1e-12, atol=1e-14)  # bit for bit on the development machine
        assert np.array_equal(got[1][:3], R[:3, 1])  # a zero turn leaves the rotation as it was

def test_likelihood_kernel_far_from_the_observation_matches_numpy():
    """Rendered depths far behind and far in front of the observation (where the kernel skips exp and erf because
    their values are exact without them) and near it give the numpy reference's log-likelihoods and posteriors."""
    from tracker.filter.depth_likelihood import (
        LikelihoodParams,
        finish_occlusion,
        occluded_likelihood,
        pixel_constants,
        update_log_likelihood,
        visible_likelihood,
    )

    prm = LikelihoodParams()
    rng = np.random.default_rng(5)
    n, k, p = 4, 3, 60
    z = rng.uniform(0.4, 1.5, p)
    offsets = np.concatenate([rng.normal(0.0, 0.004, 20), rng.uniform(0.05, 0.5, 20), -rng.uniform(0.05, 0.3, 20)])
    D = np.full((n, k, p), np.inf, np.float32)
    D[:, 0] = (z + offsets + rng.normal(0.0, 0.001, (n, p))).astype(np.float32)  # near, behind, in front
    D[:, 1, ::3] = (z[::3] + 0.3).astype(np.float32)  # a second part behind the first on some pixels
    D[:, 2, 5:15] = np.inf  # a third part that covers nothing
    D[:, 0, 40:43] = np.inf  # pixels no part covers
    o_hat = rng.uniform(0.0, 1.0, (n, p)).astype(np.float32)
    s, e, lpi = pixel_constants(z, prm)
    Df = D.reshape(n, k * p).copy()
    loc = np.arange(k * p, dtype=np.int64).reshape(k, p)
    loc[2, 30:] = -1  # part 2 cannot cover these pixels
    anc = np.arange(n)
    C, Q, F = np.zeros((n, p), np.float32), np.full((n, p), -1, np.float32), np.full((n, p), -1, np.int8)
    ell = np.zeros(n)
    dirty = np.ones((n, p), np.uint8)
    update_log_likelihood(Df, loc, np.arange(p), z, s, e, lpi, o_hat, anc, C, Q, F, ell, prm.tail_weight,
                          prm.occluder_rate, prm.tail_weight / prm.max_depth, True, dirty,
                          1.0, np.ones((k, p), np.uint8), np.zeros(k, np.uint8))
    d = D.min(axis=1).astype(np.float64)
    pv = visible_likelihood(z[None], d, prm)
    po = occluded_likelihood(z[None], d, prm)
    oh = o_hat.astype(np.float64)
    lik = pv * (1 - oh) + po * oh
    ref = np.where(np.isfinite(d), np.log(lik) - np.log(occluded_likelihood(z, np.inf, prm))[None], 0.0)
    np.testing.assert_allclose(C, ref.astype(np.float32), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(ell, ref.sum(axis=1), rtol=1e-9)
    assert np.array_equal(F, np.where(np.isfinite(d), np.argmin(D, axis=1), -1))
    post, _ = finish_occlusion(Q, F, o_hat, anc, k)
    np.testing.assert_allclose(post, np.where(np.isfinite(d), po * oh / lik, oh), atol=1e-6)


def test_banded_signed_distance_pairs_the_same_silhouette_points():
    """The signed distance with values only in a band around the blob (what the refinement uses) gives the whole
    crop's values inside the band, and the silhouette term's normal equations over contour points near and far from
    the blob are the same bit for bit."""
    import cv2

    from tracker.refine.region_term import _NO_FIELD, BAND_FAR, RegionSettings, _accumulate, _signed_distance

    rs = RegionSettings()
    band = int(np.ceil(rs.max_px)) + 4
    rng = np.random.default_rng(11)
    fx = fy = 600.0
    cx, cy = 320.0, 240.0
    cut = 0
    for trial in range(30):
        h, w = (int(x) for x in rng.integers(60, 140, 2))
        crop = np.zeros((h, w), np.uint8)
        centre = (int(rng.integers(w // 3, 2 * w // 3)), int(rng.integers(h // 3, 2 * h // 3)))
        axes = (int(rng.integers(4, w // 3)), int(rng.integers(4, h // 3)))
        cv2.ellipse(crop, centre, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
        if trial % 3 == 0:  # a blob cut by the crop's border
            crop[:, : int(rng.integers(1, w // 2))] = 1
        full = _signed_distance(crop, 0)
        banded = _signed_distance(crop, band)
        d, db = full[0], banded[0]
        kept = db != BAND_FAR
        assert np.array_equal(d[kept], db[kept])
        assert np.all(d[~kept] > rs.max_px + 2.0)
        cut += int((~kept).sum())
        # contour points (camera frame, 1 m away) projected all over the crop, near the edge and far from it
        u0, v0 = 300.0 - w / 2, 220.0 - h / 2
        uv = np.column_stack([u0 + rng.uniform(-2, w + 1, 400), v0 + rng.uniform(-2, h + 1, 400)])
        z = rng.uniform(0.8, 1.2, 400)
        pts = np.column_stack([(uv[:, 0] - cx) / fx * z, (uv[:, 1] - cy) / fy * z, z])
        R, t, c = np.eye(3), np.zeros(3), np.array([0.0, 0.0, 1.0])
        depth = np.zeros((480, 640), np.float32)
        out = []
        for sd, gu, gv in (full, banded):
            out.append(_accumulate(pts, R, t, c, sd, gu, gv, u0, v0, depth, fx, fy, cx, cy, 0.5, rs.occlusion_m,
                                   rs.depth_agree_m, rs.max_px, rs.sigma_px, rs.huber_k, rs.weight, _NO_FIELD,
                                   _NO_FIELD, 0.0))
        assert out[0][2] == out[1][2] and out[0][2] > 0
        assert np.array_equal(out[0][0], out[1][0]) and np.array_equal(out[0][1], out[1][1])
    assert cut > 0  # the band left pixels out


def above_table_points_reference(depth, intrinsics, center, radius, plane, min_height, stride, exclude):
    """The numpy form of :func:`tracker.filter.hand_carry.above_table_points` (before it moved to numba)."""
    z = float(center[2])
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    h, w = depth.shape
    zmin = max(z - radius, 0.05)
    u_c, v_c = fx * center[0] / z + cx, fy * center[1] / z + cy
    ru, rv = fx * radius / zmin, fy * radius / zmin
    u0, u1 = max(int(u_c - ru), 0), min(int(u_c + ru) + 1, w)
    v0, v1 = max(int(v_c - rv), 0), min(int(v_c + rv) + 1, h)
    d = depth[v0:v1:stride, u0:u1:stride].astype(np.float64)
    vv, uu = np.mgrid[v0:v1:stride, u0:u1:stride]
    ok = np.isfinite(d) & (d > 0)
    d, uu, vv = d[ok], uu[ok], vv[ok]
    pts = np.stack([(uu - cx) / fx * d, (vv - cy) / fy * d, d], axis=1)
    keep = ((pts - center) ** 2).sum(1) <= radius * radius
    if plane is not None:
        keep &= pts @ plane[0] + plane[1] > min_height
    for c, r in exclude:
        keep &= ((pts - c) ** 2).sum(1) > r * r
    return pts[keep]


@pytest.mark.parametrize("with_plane", [True, False])
def test_above_table_points_kernel_matches_numpy(with_plane):
    from tracker.filter.hand_carry import above_table_points

    rng = np.random.default_rng(11)
    depth = (0.55 + 0.1 * rng.random((480, 640))).astype(np.float32)
    depth[rng.random(depth.shape) < 0.05] = np.nan
    depth[rng.random(depth.shape) < 0.05] = 0.0
    normal = np.array([0.0, -0.8, -0.6])
    plane = (normal, 0.52) if with_plane else None
    kept = 0
    for _ in range(20):
        center = np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), rng.uniform(0.5, 0.65)])
        exclude = [(center + rng.normal(0.0, 0.03, 3), 0.03) for _ in range(rng.integers(0, 3))]
        for stride in (1, 2):
            got = above_table_points(depth, INTR, center, 0.1, plane, 0.01, stride, exclude)
            ref = above_table_points_reference(depth, INTR, center, 0.1, plane, 0.01, stride, exclude)
            assert got.shape == ref.shape
            assert np.array_equal(got, ref)
            kept += got.shape[0]
    assert kept > 1000  # the windows were not empty


def register_rigid_reference(src, dst, iterations, max_step, max_turn, guess=None, axis=None):
    """The numpy / KD-tree form of :func:`tracker.filter.hand_carry.register_rigid` before its rounds were compiled
    (:mod:`tracker.geometry.point_icp`); scipy's rotation conversions; without the turn fallback."""
    from scipy.spatial import cKDTree
    from scipy.spatial.transform import Rotation

    from tracker.filter.hand_carry import PAIR_BOUND, point_normals

    def rot(w):
        return Rotation.from_rotvec(w).as_matrix()

    zero = (np.zeros(3), np.zeros(3))
    tree = cKDTree(dst)
    normals = point_normals(dst, tree=tree)
    c = src.mean(axis=0)
    rel = src - c
    radius2 = max(float((rel**2).sum(1).mean()), 1e-6)
    starts = [zero]
    if guess is not None:
        starts.append(guess)
    best, best_cost = zero, np.inf
    for w, t in starts:
        w, t = w.copy(), t.copy()
        for _ in range(iterations):
            Rw = rot(w)
            moved = rel @ Rw.T + c + t
            d, j = tree.query(moved, distance_upper_bound=PAIR_BOUND)
            ok = np.isfinite(d)
            if ok.sum() < 6:
                break
            n = normals[j[ok]]
            q = moved[ok] - c - t
            r = np.einsum("mi,mi->m", n, dst[j[ok]] - moved[ok])
            Jr = np.cross(q, n)
            if axis is not None:
                Jr = (Jr @ axis)[:, None]
            nr = Jr.shape[1]
            J = np.hstack([Jr, n])
            A = J.T @ J
            lam = 1e-2 * np.trace(A[nr:, nr:]) / 3.0
            A[:nr, :nr] += lam * radius2 * np.eye(nr)
            A[nr:, nr:] += 1e-3 * np.trace(A[nr:, nr:]) * np.eye(3)
            x = np.linalg.solve(A, J.T @ r)
            dw = x[0] * axis if axis is not None else x[:3]
            w = Rotation.from_matrix(rot(dw) @ Rw).as_rotvec()
            t = t + x[nr:]
            if np.linalg.norm(x[nr:]) < 5e-5 and np.linalg.norm(dw) < 1e-4:
                break
        d, _ = tree.query(rel @ rot(w).T + c + t)
        cost = float(np.mean(np.minimum(d, PAIR_BOUND)))
        if cost < best_cost:
            best, best_cost = (w, t), cost
    w, t = best
    th, norm = float(np.linalg.norm(w)), float(np.linalg.norm(t))
    if th > max_turn:
        w = w * (max_turn / th)
    if norm > max_step:
        t = t * (max_step / norm)
    return w, t


@pytest.mark.parametrize("axis", [None, np.array([0.0, -0.8, -0.6])])
def test_compiled_hand_registration_matches_the_numpy_reference(axis):
    from scipy.spatial.transform import Rotation

    from tracker.filter.hand_carry import register_rigid

    rng = np.random.default_rng(21)
    moved_some = 0
    for trial in range(40):
        # a hand-like patch: a curved palm with a thumb, sampled unevenly; the next frame's points turned and shifted,
        # with noise, a part of them missing and clutter added
        n_palm = int(rng.integers(150, 500))
        uv = rng.uniform([-0.05, -0.035], [0.05, 0.035], (n_palm, 2))
        palm = np.column_stack([uv, 0.15 * (uv**2).sum(1)])
        thumb = rng.uniform([0.02, 0.03, -0.01], [0.035, 0.065, 0.012], (int(rng.integers(20, 120)), 3))
        src = np.vstack([palm, thumb]) + [rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), rng.uniform(0.45, 0.7)]
        c = src.mean(axis=0)
        turn = Rotation.from_rotvec(rng.normal(0.0, 0.05, 3)).as_matrix()
        shift = rng.normal(0.0, 0.006, 3)
        dst = (src - c) @ turn.T + c + shift + rng.normal(0, 0.0004, src.shape)
        dst = dst[rng.random(dst.shape[0]) > 0.15]
        dst = np.vstack([dst, c + rng.uniform(-0.08, 0.08, (30, 3))])
        guess = (rng.normal(0.0, 0.02, 3), rng.normal(0.0, 0.004, 3)) if trial % 2 else None
        iterations = int(rng.integers(1, 12))
        got = register_rigid(src, dst, iterations, 0.03, 0.2, guess, axis)
        ref = register_rigid_reference(src, dst, iterations, 0.03, 0.2, guess, axis)
        assert np.allclose(got[0], ref[0], rtol=0, atol=1e-9), (trial, got[0], ref[0])
        assert np.allclose(got[1], ref[1], rtol=0, atol=1e-9), (trial, got[1], ref[1])
        moved_some += np.linalg.norm(got[1]) > 1e-3
    assert moved_some > 20  # the registrations did move


def test_compiled_rotation_conversions_match_scipy():
    from scipy.spatial.transform import Rotation

    from tracker.geometry.point_icp import matrix_rotvec, rotvec_matrix

    rng = np.random.default_rng(5)
    for _ in range(2000):
        w = rng.normal(0.0, 10 ** rng.uniform(-6, 0.4), 3)  # tiny to large turns, both sides of the series
        if np.linalg.norm(w) > 3.1:
            continue
        R = rotvec_matrix(w)
        assert np.allclose(R, Rotation.from_rotvec(w).as_matrix(), rtol=0, atol=1e-14)
        assert np.allclose(matrix_rotvec(R), Rotation.from_matrix(R).as_rotvec(), rtol=0, atol=1e-12)


@pytest.mark.parametrize("rect", [(100.0, 300.5, 50.0, 200.0), (-np.inf, np.inf, -np.inf, np.inf),
                                  (np.inf, -np.inf, np.inf, -np.inf), (10.0, 10.0, 3.0, 400.0)])
def test_pixels_in_rect_matches_numpy(rect):
    from tracker.filter.weigh import pixels_in_rect

    rng = np.random.default_rng(3)
    pu = rng.integers(0, 640, 3000).astype(np.float64)
    pv = rng.integers(0, 480, 3000).astype(np.float64)
    ref = np.nonzero((pu >= rect[0]) & (pu <= rect[1]) & (pv >= rect[2]) & (pv <= rect[3]))[0]
    got = pixels_in_rect(pu, pv, *rect)
    assert got.dtype == np.int64
    np.testing.assert_array_equal(got, ref)
    if rect[0] < rect[1]:
        assert got.size > 0


@pytest.mark.parametrize("dtype", [np.float32, np.int8])
@pytest.mark.parametrize("ordered", [True, False])
def test_in_place_row_gather_matches_fancy_indexing(dtype, ordered):
    from tracker.filter.resampling import systematic_resample, take_rows_inplace

    rng = np.random.default_rng(3)
    for trial in range(20):
        n, m = 50 + trial, 17
        a = (rng.normal(size=(n, m)) * 50).astype(dtype)
        w = rng.random(n) ** 8  # degenerate weights: many duplicates, as a resampling that fires
        idx = systematic_resample(w / w.sum(), rng) if ordered else rng.integers(0, n, n)
        if ordered:
            assert np.all(np.diff(idx) >= 0)
        expected = a[idx]
        take_rows_inplace(a, idx)
        assert a.dtype == dtype
        np.testing.assert_array_equal(a, expected)


def _copies(rng, n_unique, n):
    """Row indices (n,) into n_unique distinct rows, copies adjacent (as a systematic resampling leaves them)."""
    return np.sort(rng.integers(0, n_unique, n))


@pytest.mark.parametrize("shape", ["box", "mesh"])
def test_renderers_give_a_copied_particle_the_depths_of_its_own_render(shape):
    """Particles whose pose equals the previous particle's take its depths (not rendered again): the depths and dirty
    flags equal rendering every particle on its own, including over earlier, different depths."""
    from tracker.geometry.box_renderer import render_boxes_at_pixels
    from tracker.geometry.mesh_renderer import render_mesh_at_pixels

    rng = np.random.default_rng(11)
    n, k, f = 40, 2, 4
    gj, gi = np.meshgrid(np.arange(30, 90), np.arange(50, 110), indexing="ij")
    gi, gj = gi.ravel().astype(np.int64), gj.ravel().astype(np.int64)
    pu, pv = (1 + f * gi).astype(np.float64), (1 + f * gj).astype(np.float64)
    rays = np.stack([(pu - INTR.cx) / INTR.fx, (pv - INTR.cy) / INTR.fy, np.ones_like(pu)], 1)
    p = gi.size
    rows = _copies(rng, 9, n)
    t = np.zeros((n, k, 3))
    t[:, 1] = np.array([0.0, 0.0, 0.6]) + rng.normal(0, 0.01, (9, 3))[rows]
    R = np.tile(np.eye(3), (n, k, 1, 1))
    R[:, 1] = rotvec_to_matrix(rng.normal(0, 0.5, (9, 3)))[rows]
    turned = rng.random(n) < 0.2  # same position as the particle before, another rotation
    R[turned, 1] = rotvec_to_matrix(rng.normal(0, 0.5, (int(turned.sum()), 3)))
    half = np.array([[0.02, 0.02, 0.02], [0.018, 0.025, 0.03]])
    center = np.zeros((k, 3))
    verts = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float) * half[1]
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6],
                      [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], np.int64)
    loc = np.full((k, p), -1, np.int64)
    loc[1, ::2] = np.arange((p + 1) // 2)  # the part's region: every other pixel
    subset = np.arange(p, dtype=np.int64)
    start = rng.choice([np.inf, 0.5, 0.7], (n, (p + 1) // 2)).astype(np.float32)  # earlier depths to change

    def run(particle_lists):
        out, dirty = start.copy(), np.zeros((n, p), np.uint8)
        for parts in particle_lists:
            if shape == "box":
                render_boxes_at_pixels(R, t, center, half, 1, parts, rays, pu, pv, subset, INTR.fx, INTR.fy,
                                       INTR.cx, INTR.cy, out, loc, dirty)
            else:
                render_mesh_at_pixels(R, t, verts, faces, 1, parts, gi, gj, subset, float(f), 1.0, INTR.fx,
                                      INTR.fy, INTR.cx, INTR.cy, out, loc, dirty)
        return out, dirty

    together = run([np.arange(n, dtype=np.int64)])
    alone = run([np.array([j], np.int64) for j in range(n)])
    assert np.isfinite(together[0]).sum() > 100  # the part is seen
    np.testing.assert_array_equal(together[0], alone[0])
    np.testing.assert_array_equal(together[1], alone[1])


def test_likelihood_kernel_reuses_a_pixel_result_only_for_equal_inputs():
    """Copied particles (equal rendered depths, mostly equal ô) next to each other give the same contributions,
    posteriors, front parts and log-likelihoods as each particle evaluated alone (nothing to reuse)."""
    from tracker.filter.depth_likelihood import LikelihoodParams, pixel_constants, update_log_likelihood

    prm = LikelihoodParams()
    rng = np.random.default_rng(8)
    n, k, p = 60, 2, 80
    z = rng.uniform(0.5, 1.0, p)
    rows = _copies(rng, 12, n)
    D = np.full((12, k, p), np.inf, np.float32)
    D[:, 0, :50] = (z[:50] + rng.normal(0, 0.005, (12, 50))).astype(np.float32)
    D[:, 1, 30:70] = (z[30:70] + rng.normal(0.01, 0.02, (12, 40))).astype(np.float32)
    D = D[rows].reshape(n, k * p)
    o_hat = rng.uniform(0, 1, (12, p)).astype(np.float32)[rows]
    o_hat[rng.random((n, p)) < 0.1] = 0.25  # copies whose ô differs at some pixels
    C0 = rng.normal(0, 1, (n, p)).astype(np.float32)
    loc = np.arange(k * p, dtype=np.int64).reshape(k, p)
    cmask = (rng.random((k, p)) < 0.8).astype(np.uint8)
    s, e, lpi = pixel_constants(z, prm)

    def run(rows_at_once):
        C, Q, F = C0.copy(), np.full((n, p), -1, np.float32), np.full((n, p), -1, np.int8)
        ell = np.zeros(n)
        dirty = np.ones((n, p), np.uint8)
        for r in rows_at_once:
            update_log_likelihood(D[r], loc, np.arange(p, dtype=np.int64), z, s, e, lpi, o_hat[r],
                                  np.arange(r.stop - r.start), C[r], Q[r], F[r], ell[r], prm.tail_weight,
                                  prm.occluder_rate, prm.tail_weight / prm.max_depth, True, dirty[r], 0.7, cmask,
                                  np.array([1, 0], np.uint8), 3.0)
        return C, Q, F, ell

    together = run([slice(0, n)])
    alone = run([slice(j, j + 1) for j in range(n)])  # one particle per call: nothing to reuse
    for a, b in zip(together, alone, strict=True):
        np.testing.assert_array_equal(a, b)


def test_colour_input_disc_median_matches_numpy():
    """The compiled gather of the blob's valid depths in the disc around the centroid (colour input's u_z) gives
    numpy's count and median, for odd and even counts, holes and NaN."""
    from tracker.filter.motion_model import _disc_median

    rng = np.random.default_rng(4)
    for _trial in range(200):
        h, w = 40, 50
        depth = rng.uniform(0.5, 0.9, (h, w)).astype(np.float32)
        depth[rng.random((h, w)) < 0.1] = np.nan
        depth[rng.random((h, w)) < 0.1] = 0.0
        mask = rng.random((h, w)) < 0.7
        px, py = rng.uniform(0, w), rng.uniform(0, h)
        r = rng.uniform(0.3, 9.0)
        u0, u1 = max(0, int(round(px)) - 9), min(w, int(round(px)) + 10)
        v0, v1 = max(0, int(round(py)) - 9), min(h, int(round(py)) + 10)
        patch = depth[v0:v1, u0:u1]
        vv, uu = np.mgrid[v0:v1, u0:u1]
        inside = ((uu - px) ** 2 + (vv - py) ** 2 <= max(r, 0.5) ** 2) & mask[v0:v1, u0:u1]
        vals = patch[inside & np.isfinite(patch) & (patch > 0)]
        n, med = _disc_median(depth, mask, u0, u1, v0, v1, px, py, max(r, 0.5) ** 2)
        assert n == vals.size
        if vals.size:
            assert med == float(np.median(vals))


@pytest.mark.parametrize("wide", [(0.0, 1.0), (0.2, 3.0), (0.5, 1.0)])
def test_noise_samples_match_the_numpy_form(wide):
    """The motion noise scaled in one compiled pass gives the numpy form's samples from the same random stream."""
    from tracker.filter.motion_model import sample_noise

    def numpy_form(rng, m, sigma_v, sigma_w, wide_fraction, wide_scale):
        w = rng.standard_normal((m, 6))
        scale = np.ones(m)
        if wide_fraction > 0.0 and wide_scale != 1.0:
            scale = np.where(rng.random(m) < wide_fraction, wide_scale, 1.0)
        w[:, :3] *= (sigma_v * scale)[:, None]
        w[:, 3:] *= (sigma_w * scale)[:, None]
        return w

    a, b = np.random.default_rng(9), np.random.default_rng(9)
    for sigma_v, sigma_w in ((0.002, 0.03), (1e-4, 0.7), (0.013, 0.0)):
        got = sample_noise(a, 225, sigma_v, sigma_w, *wide)
        want = numpy_form(b, 225, sigma_v, sigma_w, *wide)
        assert np.array_equal(got, want)
    assert a.random() == b.random()  # the same draws taken from the stream


def test_mean_poses_of_all_parts_equal_each_part_alone():
    """The estimate of every part in one call gives each part's :func:`mean_pose` bit for bit."""
    from tracker.filter.motion_model import mean_pose, mean_poses

    rng = np.random.default_rng(12)
    for n, k in ((225, 7), (50, 1), (31, 3)):
        p = rng.normal(0.0, 0.2, (n, k, 3))
        R = np.stack([rotvec_to_matrix(rng.normal(0.0, 0.3, 3) + rng.normal(0.0, 0.05, (n, 3))) for _ in range(k)], 1)
        w = rng.random(n) ** 4
        got = mean_poses(p, R, w / w.sum())
        for i in range(k):
            want = mean_pose(p[:, i], R[:, i], w / w.sum())
            assert np.array_equal(got[i].t, want.t) and np.array_equal(got[i].q, want.q)


def test_box_depth_at_one_pixel_matches_the_renderer():
    """The colour input's one-pixel surface depth gives the box renderer's float32 depth (hits, misses, a box
    partly behind the camera)."""
    from types import SimpleNamespace

    from tracker.filter.colour_input import _box_depth_at, box_surface_depth

    rng = np.random.default_rng(6)
    half = np.array([[0.018, 0.018, 0.025]])
    center = np.array([[0.0, 0.0, 0.004]])
    hits = 0
    for trial in range(300):
        t = np.array([rng.normal(0, 0.1), rng.normal(0, 0.1), 0.03 if trial % 50 == 0 else rng.uniform(0.3, 1.2)])
        pose = Pose.from_rt(rotvec_to_matrix(rng.normal(0, 1.0, 3))[0], t)
        trk = SimpleNamespace(estimates={"a": pose}, names=["a"], center=center, half=half, intrinsics=INTR)
        uv = INTR.project(t[None])[0] + rng.normal(0, 15, 2)
        want = box_surface_depth(trk, 0, np.array([uv[0]]), np.array([uv[1]]))[0]
        got = _box_depth_at(np.ascontiguousarray(pose.R), pose.t, center[0], half[0], float(uv[0]), float(uv[1]),
                            INTR.fx, INTR.fy, INTR.cx, INTR.cy)
        assert got == want or (np.isnan(got) and np.isnan(want))
        hits += bool(np.isfinite(want))
    assert 50 < hits < 300


def test_correction_rotation_kernel_matches_einsum():
    """The refinement's correction turns the particles' rotations exactly as ``np.einsum("ij,njk->nik")`` did (a
    contiguous stack and a part's strided column of the tracker's (N, K, 3, 3) array)."""
    from tracker.filter.motion_model import rotate_left

    rng = np.random.default_rng(7)
    for _ in range(20):
        Rd = rotvec_to_matrix(rng.normal(0.0, 0.5, 3))[0]
        R_all = rotvec_to_matrix(rng.normal(0.0, 1.0, (60 * 4, 3))).reshape(60, 4, 3, 3)
        for R in (R_all[:, 2], np.ascontiguousarray(R_all[:, 1])):
            assert np.array_equal(rotate_left(Rd, R), np.einsum("ij,njk->nik", Rd, R))


def test_rotation_angle_matches_the_numpy_form():
    """The refinement's rotation angle on Python floats equals ``arccos(clip((trace − 1) / 2))`` in numpy, also at
    the clipped ends (identity, half turn, a matrix a little off orthonormal)."""
    from tracker.refine.part_refiner import rotation_angle

    rng = np.random.default_rng(8)
    mats = list(rotvec_to_matrix(rng.normal(0.0, 1.5, (500, 3))))
    mats += [np.eye(3), np.diag([1.0, -1.0, -1.0]), np.eye(3) * (1.0 + 1e-12), -np.eye(3) * (1.0 + 1e-12)]
    for R in mats:
        want = float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))
        assert rotation_angle(R) == want


def test_scene_motion_agreement_table_matches_agrees():
    """The consensus's agreement table gives :func:`agrees`'s answer for every candidate and landmark (landmark
    motions near one camera motion, some off by more than the tolerance in place or in turn)."""
    from tracker.filter.scene_motion import agreement, agrees

    rng = np.random.default_rng(9)
    tol = 0.003
    agreeing = sum_pairs = 0
    for _ in range(40):
        m = int(rng.integers(2, 8))
        sum_pairs += m * (m - 1)
        R0 = rotvec_to_matrix(rng.normal(0.0, 0.05, 3))[0]
        t0 = rng.normal(0.0, 0.01, 3)
        Rs = np.stack([rotvec_to_matrix(rng.normal(0.0, 0.003, 3))[0] @ R0 for _ in range(m)])
        ts = t0 + rng.normal(0.0, 0.0015, (m, 3))
        cs = rng.normal(0.0, 0.1, (m, 3)) + [0.0, 0.0, 0.6]
        table = agreement(Rs, ts, cs, tol)
        for a in range(m):
            for j in range(m):
                assert table[a, j] == agrees(Rs[a], ts[a], Rs[j], ts[j], cs[j], tol)
                agreeing += bool(table[a, j]) and a != j
    assert 20 < agreeing < sum_pairs


def test_weighted_positions_match_numpy_sums():
    """The state estimate's weighted mean positions of all parts in one kernel equal numpy's per-part sums."""
    from tracker.filter.motion_model import weighted_positions

    rng = np.random.default_rng(10)
    for n, k in ((225, 7), (50, 1), (1, 3)):
        p = rng.normal(0.0, 0.2, (n, k, 3)) + [0.0, 0.0, 0.7]
        w = rng.random(n) ** 3
        w /= w.sum()
        want = np.stack([(w[:, None] * p[:, i]).sum(axis=0) for i in range(k)])
        assert np.array_equal(weighted_positions(w, p), want)


def test_intersects_others_matches_the_stacked_form():
    """The refinement's interpenetration test of a corrected part against the others' estimates (arrays filled in
    place) answers as the form that stacked every pose's matrices did, on touching and overlapping cubes."""
    from tracker.filter.penalties import intersection_flags
    from tracker.refine.refine_stage import intersects_others, pose_stack

    parts = [PartSpec(f"c{i}", box=(0.03, 0.03, 0.03)) for i in range(4)]
    trk = MultiObjectTracker(parts, INTR, TrackerConfig.preset("default").with_overrides(n_particles=8), seed=0)
    rng = np.random.default_rng(11)
    hits = 0
    for _ in range(60):
        poses = {p.name: Pose.from_rt(rotvec_to_matrix(rng.normal(0.0, 1.0, 3))[0],
                                      [rng.uniform(-0.04, 0.04), rng.uniform(-0.04, 0.04), 0.6]) for p in parts}
        obj = int(rng.integers(0, 4))
        moved = poses[trk.names[obj]].t + rng.normal(0, 0.01, 3)
        pose = Pose.from_rt(rotvec_to_matrix(rng.normal(0.0, 1.0, 3))[0], moved)
        R = np.stack([pose.R if i == obj else poses[n].R for i, n in enumerate(trk.names)])[None]
        t = np.stack([pose.t if i == obj else poses[n].t for i, n in enumerate(trk.names)])[None]
        pairs = np.array([(obj, o) for o in range(4) if o != obj], np.int64)
        want = bool(intersection_flags(R, t, trk.center, trk.half, pairs, trk.config.contact_tolerance)[0])
        assert intersects_others(trk, obj, pose, poses) == want
        # with the estimates stacked once (the refinement stage's form): the same answer, the stack left as it was
        stack = pose_stack(trk, poses)
        kept = (stack[0].copy(), stack[1].copy())
        assert intersects_others(trk, obj, pose, poses, stack) == want
        assert np.array_equal(stack[0], kept[0]) and np.array_equal(stack[1], kept[1])
        hits += want
    assert 5 < hits < 60


def test_blob_area_counts_the_blob_mask():
    """The blob area counted once when a blob's mask is made equals the mask's pixel count (blobs inside the image,
    cut by its border, too thin to survive the erosion)."""
    from types import SimpleNamespace

    from tracker.filter.colour_input import blob_area, blob_mask

    cfg = TrackerConfig.preset("default")
    rng = np.random.default_rng(12)
    shape = (480, 640)
    counted = 0
    for trial in range(40):
        trk = SimpleNamespace(config=cfg, _blobs={})
        c = rng.uniform([-20, -20], [660, 500])
        r = rng.uniform(1.0, 40.0, 2) if trial % 10 else np.array([1.0, 30.0])
        ang = np.linspace(0, 2 * np.pi, 12, endpoint=False)
        contour = np.stack([c[0] + r[0] * np.cos(ang), c[1] + r[1] * np.sin(ang)], 1).round().astype(np.int32)
        det = SimpleNamespace(contour=contour[:, None, :], score=1.0)
        mask = blob_mask(trk, det, shape)
        assert blob_area(trk, det, shape) == int(np.count_nonzero(mask))
        counted += int(np.count_nonzero(mask)) > 0
    assert 10 < counted < 40


def test_prior_terms_kept_per_part_equal_the_priors_from_scratch():
    """The support prior kept per part during the coordinate passes (only the moved part recomputed, rows following
    resamplings) and the rest prior's kernel equal their numpy forms computed from scratch."""
    from tracker.filter import hidden_parts

    parts = [PartSpec(f"c{i}", box=(0.03, 0.03, 0.04)) for i in range(4)]
    n = 40
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=n, rest_prior_sigma=0.01,
                                                         support_prior_sigma=0.004)
    trk = MultiObjectTracker(parts, INTR, cfg, seed=0)
    rng = np.random.default_rng(13)
    trk.initialize({p.name: Pose.from_rt(rotvec_to_matrix(rng.normal(0, 0.3, 3))[0], [0.05 * i, 0.0, 0.6])
                    for i, p in enumerate(parts)})
    trk._rest_on = np.array([True, False, True, True])
    trk._support_on = np.array([True, True, False, True])
    plane = (np.array([0.0, -0.8, -0.6]), 0.45)
    priors = hidden_parts.PriorTerms(trk, plane)
    p, R = trk.p.copy(), trk.R.copy()
    for step in range(12):
        changed = None if step == 0 else {step % 4}
        for i in (range(4) if changed is None else changed):
            p[:, i] += rng.normal(0.0, 0.004, (n, 3))
            R[:, i] = rotvec_to_matrix(rng.normal(0.0, 0.05, (n, 3))) @ R[:, i]
        rest, support = priors.total(p, R, changed)
        on = trk._rest_on
        sig2 = cfg.rest_prior_sigma ** 2  # log_rest_prior's numpy form
        want_rest = -0.5 * np.minimum(((p[:, on] - trk._rest_t[on]) ** 2).sum(-1), 9.0 * sig2).sum(-1) / sig2
        assert np.array_equal(hidden_parts.log_rest_prior(trk, p), want_rest)
        want = want_rest + hidden_parts.log_support_prior(trk, p, R, plane)
        assert np.array_equal(rest + support, want)
        if step % 3 == 2:  # a resampling
            idx = np.sort(rng.integers(0, n, n))
            p, R = p[idx], R[idx]
            priors.take(idx)
    rest, support = hidden_parts.PriorTerms(trk, None).total(p, R, None)  # no plane: no support prior
    assert isinstance(rest, np.ndarray) and support == 0.0
    trk._rest_on[:] = False
    assert hidden_parts.PriorTerms(trk, None).total(p, R, None) == (0.0, 0.0)


@pytest.mark.parametrize("k", [1, 3, 7, 9])
def test_rest_prior_kernel_matches_numpy(k):
    """The rest prior of up to 7 resting parts (the kernel) and of more (numpy's pairwise sums) equal the numpy
    form."""
    from types import SimpleNamespace

    from tracker.filter.hidden_parts import log_rest_prior

    rng = np.random.default_rng(14 + k)
    cfg = TrackerConfig.preset("default").with_overrides(rest_prior_sigma=0.01)
    for _ in range(20):
        p = rng.normal(0.0, 0.02, (225, k, 3))
        on = rng.random(k) < 0.8
        on[0] = True
        trk = SimpleNamespace(config=cfg, _rest_on=on, _rest_t=rng.normal(0.0, 0.02, (k, 3)))
        sig2 = 0.01 ** 2
        want = -0.5 * np.minimum(((p[:, on] - trk._rest_t[on]) ** 2).sum(-1), 9.0 * sig2).sum(-1) / sig2
        assert np.array_equal(log_rest_prior(trk, p), want)


def test_projection_kernel_matches_numpy():
    """:meth:`Intrinsics.project` in numba equals its numpy form, also for a point at Z = 0 and a NaN point."""
    intr = Intrinsics(640, 480, 612.3, 611.7, 319.4, 241.2)
    rng = np.random.default_rng(15)
    for _ in range(50):
        p = rng.normal(0.0, 0.3, (40, 3))
        p[:, 2] = rng.normal(0.6, 0.5, 40)
        p[0, 2] = 0.0
        p[1] = np.nan
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            want = np.stack([intr.fx * p[:, 0] / z + intr.cx, intr.fy * p[:, 1] / z + intr.cy], axis=1)
        assert np.array_equal(intr.project(p), want, equal_nan=True)
    assert intr.project(np.array([0.1, -0.05, 0.5])).shape == (1, 2)


def test_blob_mask_matches_its_reference_form():
    """A blob's mask (window from cv2.boundingRect, one erosion kernel for all) equals the form that took the
    window from the contour's min and max, for blobs inside the image and cut by its border."""
    import cv2

    from tracker.filter.colour_input import make_blob_mask

    def reference(contour, shape):
        pts = np.asarray(contour, np.int32).reshape(-1, 2)
        x0, y0 = max(int(pts[:, 0].min()) - 3, 0), max(int(pts[:, 1].min()) - 3, 0)
        x1, y1 = min(int(pts[:, 0].max()) + 4, shape[1]), min(int(pts[:, 1].max()) + 4, shape[0])
        m = np.zeros(shape, bool)
        if x0 >= x1 or y0 >= y1:
            return m
        win = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.fillPoly(win, [pts - np.array([x0, y0], np.int32)], 1)
        m[y0:y1, x0:x1] = cv2.erode(win, np.ones((5, 5), np.uint8)).astype(bool)
        return m

    from types import SimpleNamespace

    trk = SimpleNamespace(config=TrackerConfig.preset("default"))
    rng = np.random.default_rng(16)
    for _ in range(60):
        c = rng.uniform([-30, -30], [670, 510])
        r = rng.uniform(2.0, 50.0, 2)
        ang = np.sort(rng.uniform(0, 2 * np.pi, 10))
        contour = np.stack([c[0] + r[0] * np.cos(ang), c[1] + r[1] * np.sin(ang)], 1).round().astype(np.int32)
        det = SimpleNamespace(contour=contour[:, None, :], score=1.0)
        assert np.array_equal(make_blob_mask(trk, det, (480, 640)), reference(contour, (480, 640)))


def test_support_prior_kernel_matches_numpy():
    """The support prior's per-part term in one kernel gives the numpy form's values (bit for bit on the development
    machine; :func:`_close_to_ulps`) for strided parts of the particle arrays, hulls of several sizes, tilted tables,
    any particle count from two on."""
    from tracker.filter.hidden_parts import _support_kernel, _support_numpy

    rng = np.random.default_rng(7)
    for n in (2, 3, 5, 20, 100, 225):
        for _ in range(10):
            k = int(rng.integers(1, 8))
            i = int(rng.integers(0, k))
            hull = rng.uniform(-0.03, 0.03, (int(rng.integers(4, 30)), 3))
            p = rng.normal(0.0, 0.3, (n, k, 3))
            R = np.stack([rotvec_to_matrix(rng.normal(0.0, 1.0, (n, 3))) for _ in range(k)], axis=1)
            normal = rng.normal(size=3)
            normal /= np.linalg.norm(normal)
            d = float(rng.normal() * 0.5)
            want = _support_numpy(p, R, normal, d, hull, i, 0.003)
            got = _support_kernel(p, R, normal, d, hull, i, 0.003)
            assert np.allclose(got, want, rtol=1e-12, atol=1e-12)  # bit for bit on the development machine
            assert (want > 0).any()


def test_warm_up_loads_the_kernels_a_session_calls_later():
    """A tracker's warm-up gives the rest and support priors' kernels and the hand carry's point and registration
    kernels the very signatures the session's calls use: calling them as the session does adds no new one (it would
    be compiled or loaded from the cache mid-session, tens of ms in one frame)."""
    from tracker.filter import footprint_depth, hand_carry, hidden_parts
    from tracker.geometry import depth_points, point_icp

    parts = [PartSpec(f"c{i}", box=(0.03, 0.03, 0.04)) for i in range(3)]
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=30)
    trk = MultiObjectTracker(parts, INTR, cfg, seed=0)
    kernels = [hidden_parts._rest_prior, hidden_parts._support_kernel, depth_points.window_points,
               point_icp.build_grid, point_icp.rigid_icp, hidden_parts._behind_surface,
               footprint_depth._footprint_counts]
    before = [list(k.signatures) for k in kernels]
    assert all(before)
    rng = np.random.default_rng(3)
    trk.initialize({p.name: Pose.from_rt(np.eye(3), [0.05 * i, 0.0, 0.6]) for i, p in enumerate(parts)})
    trk._rest_on = np.array([True, False, True])
    trk._rest_t = trk.p[0].copy()
    plane = (np.array([0.0, -0.8, -0.6]), 0.45)
    p = trk.p + rng.normal(0.0, 0.003, trk.p.shape)
    assert hidden_parts.log_rest_prior(trk, p).shape == (30,)
    assert hidden_parts._support_term(trk, p, trk.R, plane, 1).shape == (30,)
    depth = np.full((INTR.height, INTR.width), 0.6, np.float32)
    pts = hand_carry.above_table_points(depth, INTR, np.array([0.0, 0.0, 0.6]), 0.05, plane, 0.01, 4,
                                        [(np.array([0.02, 0.0, 0.6]), 0.01)])
    assert pts.shape[0] > 6
    w, t = hand_carry.register_rigid(pts, pts + np.array([0.002, 0.0, 0.0]), 5, 0.01, 0.2)
    assert np.isfinite(w).all() and np.isfinite(t).all()
    assert hidden_parts.revealed(trk, 1, depth) in (True, False)  # the depth shows the cube's surface: not revealed
    assert footprint_depth.classify_footprint(trk, 1, depth, plane) is not None
    assert [list(k.signatures) for k in kernels] == before


def test_refiner_corner_bounds_kernel_matches_numpy():
    """:func:`tracker.refine.part_refiner._corner_bounds` gives the bounds of the numpy form it replaced
    (``corners @ R.T + t``, projected, min / max) bit for bit, and its near-camera flag: random cube poses, boxes
    with an offset centre, corners near and behind the camera plane."""
    from scipy.spatial.transform import Rotation

    from tracker.refine.part_refiner import _corner_bounds

    rng = np.random.default_rng(17)
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    n_near = 0
    for trial in range(3000):
        corners = signs * rng.uniform(0.01, 0.05, 3) + rng.normal(0.0, 0.01, 3)
        R = Rotation.from_rotvec(rng.normal(0.0, 1.5, 3)).as_matrix()
        t = np.array([rng.normal(0.0, 0.2), rng.normal(0.0, 0.2), rng.uniform(-0.05, 0.8)])
        pts = corners @ R.T + t
        z = pts[:, 2]
        u = INTR.fx * pts[:, 0] / z + INTR.cx
        v = INTR.fy * pts[:, 1] / z + INTR.cy
        got = _corner_bounds(corners, R, t, INTR.fx, INTR.fy, INTR.cx, INTR.cy)
        assert got[4] == bool((z < 0.02).any())
        n_near += got[4]
        with np.errstate(all="ignore"):
            ref = (float(u.min()), float(v.min()), float(u.max()), float(v.max()))
        assert np.array_equal(np.array(got[:4]), np.array(ref), equal_nan=True), trial
    assert 100 < n_near < 2900


@pytest.mark.parametrize("n", [1, 5, 8, 9, 64, 128, 129, 225, 1000])
def test_pairwise_sum_kernel_adds_as_numpy_sum(n):
    from tracker.filter.resampling import pairwise_sum

    rng = np.random.default_rng(n)
    for _ in range(200):
        x = rng.standard_normal(n) * 10.0 ** rng.uniform(-3, 3, n)
        assert pairwise_sum(x, 0, n) == x.sum()
    # a misordered sum (plain running total) differs on these inputs: the test can tell the orders apart
    if n >= 9:
        assert any(pairwise_sum(x, 0, n) != float(np.cumsum(x)[-1])
                   for x in (rng.standard_normal(n) * 10.0 ** rng.uniform(-3, 3, n) for _ in range(200)))


def _numpy_has_avx512() -> bool:
    """Whether numpy dispatches its float64 exp/log to AVX-512 code on this CPU (whose rounding may differ by an ulp
    from the C library's, which numba's kernels call)."""
    feats = getattr(np._core._multiarray_umath, "__cpu_features__", {})
    return bool(feats.get("AVX512F", False) or feats.get("AVX512_SKX", False))


@pytest.mark.parametrize("case", ["random", "minus_inf", "nan", "all_minus_inf", "one_hot"])
def test_reweigh_kernel_matches_the_numpy_weight_update(case):
    from tracker.filter.resampling import kl_from_uniform, normalize_log_weights, reweigh

    rng = np.random.default_rng(7)
    n = 225
    for _ in range(50):
        log_w = rng.normal(-5.4, 3.0, n)
        ell_tot = rng.normal(0.0, 40.0, n)
        ell_prev = rng.normal(0.0, 40.0, n)
        if case == "minus_inf":
            ell_tot[rng.integers(0, n, 20)] = -np.inf
        elif case == "nan":
            ell_tot[3] = np.nan
        elif case == "all_minus_inf":
            ell_tot[:] = -np.inf
        elif case == "one_hot":
            ell_tot[:] = -1e6
            ell_tot[11] = 0.0
        # the numpy form of coordinate_passes before the kernel
        ref = log_w.copy()
        ref += ell_tot - ell_prev
        w_ref = normalize_log_weights(ref)
        ref = np.log(np.maximum(w_ref, 1e-300))
        kl_ref = kl_from_uniform(w_ref)
        got, w = log_w.copy(), np.empty(n)
        kl = reweigh(got, ell_tot, ell_prev, w)
        # The kernel's exp/log are the C library's; numpy uses its own SIMD forms on CPUs with AVX-512, which may
        # round the last bit differently: equal to within a few units in the last place, bit for bit elsewhere.
        np.testing.assert_array_max_ulp(w, w_ref, maxulp=4)
        np.testing.assert_array_max_ulp(got, ref, maxulp=4)
        assert abs(kl - kl_ref) <= 1e-12 * max(1.0, abs(kl_ref))
        if not _numpy_has_avx512():
            assert np.array_equal(w, w_ref) and np.array_equal(got, ref) and kl == kl_ref


def _classify_footprint_reference(trk, obj, depth, plane, stride=2):
    """The numpy form of :func:`tracker.filter.footprint_depth.classify_footprint` (before its compiled counts)."""
    from tracker.filter.blob_follow import footprint
    from tracker.filter.colour_input import box_surface_depth
    from tracker.filter.footprint_depth import SURFACE_TOLERANCE_M, TABLE_TOLERANCE_M, FootprintDepth
    from tracker.geometry.box_renderer import pixel_rays

    fp = footprint(trk, obj)
    if fp is None:
        return None
    h, w = depth.shape[:2]
    u0, v0 = max(int(np.floor(fp[0])), 0), max(int(np.floor(fp[1])), 0)
    u1, v1 = min(int(np.ceil(fp[2])) + 1, w), min(int(np.ceil(fp[3])) + 1, h)
    if u1 <= u0 or v1 <= v0:
        return None
    vv, uu = np.mgrid[v0:v1:stride, u0:u1:stride]
    uu, vv = uu.ravel(), vv.ravel()
    surface = box_surface_depth(trk, obj, uu, vv)
    on = np.isfinite(surface)
    if not on.any():
        return None
    uu, vv, surface = uu[on], vv[on], surface[on]
    z = np.asarray(depth[vv, uu], np.float64)
    valid = np.isfinite(z) & (z > 0)
    diff = np.where(valid, z - surface, 0.0)
    nearer = valid & (diff < -SURFACE_TOLERANCE_M)
    shown = valid & (np.abs(diff) <= SURFACE_TOLERANCE_M)
    behind = valid & (diff > SURFACE_TOLERANCE_M)
    table = np.zeros_like(behind)
    if plane is not None and behind.any():
        normal, offset = np.asarray(plane[0], np.float64), float(plane[1])
        pts = pixel_rays(trk.intrinsics, uu[behind].astype(np.float64), vv[behind].astype(np.float64))
        pts = pts * z[behind][:, None]
        table[behind] = np.abs(pts @ normal + offset) <= TABLE_TOLERANCE_M
    return FootprintDepth(int(len(z)), float(1.0 - valid.mean()), float(nearer.mean()), float(shown.mean()),
                          float(behind.mean()), float(table.mean()))


def _revealed_reference(trk, obj, depth):
    """The numpy form of :func:`tracker.filter.hidden_parts.revealed` with ``revealed_surface`` (before its
    compiled surface test)."""
    from tracker.filter.colour_input import box_surface_depth
    from tracker.filter.hidden_parts import estimate_rect

    rect = estimate_rect(trk, obj, depth.shape)
    if rect is None:
        return False
    u0, v0, u1, v1 = rect
    du, dv = (u1 - u0) // 4, (v1 - v0) // 4
    patch = depth[v0 + dv : v1 - dv, u0 + du : u1 - du]
    if patch.size < 16:
        return False
    valid = np.isfinite(patch) & (patch > 0)
    if valid.mean() < trk.config.carry_revealed_fraction:
        return False
    vv, uu = np.nonzero(valid)
    surface = box_surface_depth(trk, obj, uu + u0 + du, vv + v0 + dv)
    on = np.isfinite(surface)
    if on.mean() < 0.5:
        return False
    return bool((patch[valid][on] > surface[on] + 0.015).mean() > 0.9)


def test_footprint_and_see_through_kernels_match_their_numpy_forms():
    """The hidden-parts stage's footprint classification and see-through test (compiled counts) give the numpy
    forms' results on cubes at seeded poses over seeded depth (the table, the cube itself, a hand in front, holes,
    depth just behind the surface), every outcome of both tests occurring."""
    from tracker.filter.footprint_depth import classify_footprint
    from tracker.filter.hidden_parts import revealed

    parts = [PartSpec("c0", box=(0.036, 0.036, 0.036)), PartSpec("c1", box=(0.03, 0.05, 0.04))]
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=8, revealed_surface=True)
    trk = MultiObjectTracker(parts, INTR, cfg, seed=0)
    rng = np.random.default_rng(21)
    vv, uu = np.mgrid[0:INTR.height, 0:INTR.width]
    outcomes, revealed_seen = set(), set()
    for trial in range(120):
        reach = 0.25 if trial % 4 else 0.9  # every fourth part may lie (partly) off the image
        poses = {p.name: Pose.from_rt(rotvec_to_matrix(rng.normal(0.0, 0.8, 3))[0],
                                      [rng.uniform(-reach, reach), rng.uniform(-0.2, 0.2), rng.uniform(0.3, 0.9)])
                 for p in parts}
        trk.initialize(poses)
        obj = trial % 2
        est = trk.estimates[trk.names[obj]]
        table_z = float(est.t[2]) + rng.choice([-0.1, 0.012, 0.02, 0.2])  # in front, just behind, behind
        tilt = rng.normal(0.0, 0.3, 2)
        depth = (table_z + tilt[0] * (uu - 320) / 600.0 + tilt[1] * (vv - 240) / 600.0).astype(np.float32)
        holes = rng.random(depth.shape) < rng.choice([0.0, 0.3, 0.7])
        depth[holes] = rng.choice([np.nan, 0.0])
        normal = np.array([0.0, -tilt[1], -1.0]) / np.linalg.norm([0.0, tilt[1], 1.0])
        plane = None if trial % 5 == 0 else (normal, float(-normal @ np.array([0.0, 0.0, table_z])))
        want = _classify_footprint_reference(trk, obj, depth, plane)
        got = classify_footprint(trk, obj, depth, plane)
        assert got == want
        if want is not None:
            outcomes.add((want.nearer > 0, want.shown > 0, want.behind > 0, want.table > 0))
        r = revealed(trk, obj, depth)
        assert r == _revealed_reference(trk, obj, depth)
        revealed_seen.add(r)
    assert len(outcomes) >= 4 and any(o[3] for o in outcomes) and revealed_seen == {True, False}


def test_area_ratio_hull_projection_kernel_matches_numpy():
    """The colour input's projected hull (one kernel) gives ``intrinsics.project(pose.transform_points(hull))`` as
    float32, bit for bit, on seeded poses and hulls of several sizes, and declines when a point is within 1 cm of the
    camera plane as the numpy form does."""
    from tracker.filter.colour_input import _hull_pixels

    rng = np.random.default_rng(17)
    declined = 0
    for trial in range(1500):
        hull = rng.normal(0.0, 0.03, ((8, 12, 50)[trial % 3], 3))
        pose = Pose.from_rt(rotvec_to_matrix(rng.normal(0.0, 1.0, 3))[0],
                            [rng.normal(0.0, 0.2), rng.normal(0.0, 0.2), rng.uniform(0.0, 0.9)])
        pts = pose.transform_points(hull)
        ok, uv = _hull_pixels(hull, np.ascontiguousarray(pose.R), pose.t, INTR.fx, INTR.fy, INTR.cx, INTR.cy)
        assert ok == (not np.any(pts[:, 2] < 0.01))
        if ok:
            assert np.array_equal(uv, INTR.project(pts).astype(np.float32))
        declined += not ok
    assert 50 < declined < 1400
