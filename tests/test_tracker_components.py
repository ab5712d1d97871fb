"""Unit tests of the depth tracker's components: likelihood, occlusion, resampling, rendering, penalties,
connection particles, rotation mean, configuration. Synthetic inputs only (no simulator)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.stats import norm

from tracker.filter.connection_hint import ConnectionHint
from tracker.filter.connection_particles import apply_connections, resolve_hints
from tracker.filter.depth_likelihood import (
    LikelihoodParams,
    depth_sigma,
    finish_occlusion,
    occluded_likelihood,
    pixel_constants,
    predict_occlusion,
    update_log_likelihood,
    visible_likelihood,
)
from tracker.filter.motion_model import mean_rotation, propagate, rotvec_to_matrix
from tracker.filter.penalties import boxes_intersect, lowest_heights, table_log_penalty
from tracker.filter.resampling import kl_from_uniform, normalize_log_weights, systematic_resample
from tracker.filter.tracker_config import PRESETS, TrackerConfig
from tracker.geometry.box_renderer import render_box_depth
from tracker.geometry.camera import Intrinsics
from tracker.geometry.mesh_renderer import MeshModel, render_mesh_at_pixels
from tracker.geometry.parts import CUBE_EDGE, PartSpec
from tracker.geometry.pose import Pose

PRM = LikelihoodParams()


# ---------------------------------------------------------------- likelihood (spec 4.9, 4.10)
@pytest.mark.parametrize("d,z", [(0.8, 0.8), (0.8, 0.79), (0.8, 0.5), (1.2, 0.3), (0.6, 0.62)])
def test_occluded_closed_form_matches_numeric_integral(d, z):
    """(4.34) stable form equals ∫ p(z|b) p(b|a=d, o=1) db of (4.31)–(4.32) (σ_m = 0, z ≫ σ)."""
    s = float(depth_sigma(z, PRM))
    lam, beta, m = PRM.occluder_rate, PRM.tail_weight, PRM.max_depth

    def integrand(b):
        return norm.pdf(z, b, s) * lam * math.exp(-lam * b) / (1.0 - math.exp(-lam * d))

    val, _ = quad(integrand, 0.0, d, points=[z], limit=200)
    expected = (1 - beta) * val + beta / m
    assert float(occluded_likelihood(z, d, PRM)) == pytest.approx(expected, rel=1e-4)


def test_visible_likelihood_and_no_object_limit():
    z, d = 0.8, 0.803
    s = float(depth_sigma(z, PRM))
    assert s == pytest.approx(0.003 + 0.00142478 * 0.64)
    expected = (1 - PRM.tail_weight) * norm.pdf(z, d, s) + PRM.tail_weight / PRM.max_depth
    assert float(visible_likelihood(z, d, PRM)) == pytest.approx(expected)
    # d = inf: p_v = β/m, p_o = β/m + (1 − β) λ exp(½λ(λσ² − 2z))
    assert float(visible_likelihood(z, np.inf, PRM)) == pytest.approx(PRM.tail_weight / PRM.max_depth)
    lam = PRM.occluder_rate
    po_inf = PRM.tail_weight / PRM.max_depth + (1 - PRM.tail_weight) * lam * math.exp(0.5 * lam * (lam * s * s - 2 * z))
    assert float(occluded_likelihood(z, np.inf, PRM)) == pytest.approx(po_inf)
    # a surface far in front of the observation ("see-through") is nearly impossible under both hypotheses
    assert float(occluded_likelihood(0.9, 0.7, PRM)) == pytest.approx(PRM.tail_weight / PRM.max_depth, rel=1e-3)


def test_occlusion_prediction_rate_form():
    # Δt = 1 reduces to the one-step transition
    o = np.array([0.0, 0.3, 1.0])
    one = predict_occlusion(o, 1.0, 0.1, 0.7)
    assert np.allclose(one, 0.7 * o + 0.1 * (1 - o))
    # per-frame values at 30 fps quoted in the spec
    assert float(predict_occlusion(0.0, 1 / 30, 0.1, 0.7)) == pytest.approx(0.0042, abs=2e-4)
    assert float(predict_occlusion(1.0, 1 / 30, 0.1, 0.7)) == pytest.approx(0.9873, abs=2e-4)
    # long gaps converge to the stationary probability 0.25; Δt = 0 keeps the value
    assert float(predict_occlusion(0.9, 100.0, 0.1, 0.7)) == pytest.approx(0.25, abs=1e-6)
    assert np.allclose(predict_occlusion(o, 0.0, 0.1, 0.7), o)


def test_likelihood_kernel_matches_numpy_reference():
    rng = np.random.default_rng(0)
    n, k, p = 3, 2, 40
    z = rng.uniform(0.5, 1.2, p)
    D = np.full((n, k, p), np.inf, np.float32)
    D[:, 0, :25] = (z[:25] + rng.normal(0, 0.01, (n, 25))).astype(np.float32)
    D[:, 1, 20:35] = (z[20:35] - 0.02).astype(np.float32)
    D[:, 1, 30] = np.float32(z[30] + 0.1)  # the part lies 10 cm behind the observed surface: occluded
    o_hat = rng.uniform(0, 1, (n, p)).astype(np.float32)
    s, e, lpi = pixel_constants(z, PRM)
    Df = D.reshape(n, k * p).copy()  # one depth column per (part, pixel)
    loc = np.arange(k * p, dtype=np.int64).reshape(k, p)
    anc = np.arange(n)

    def run(cm, cv):
        C, Q, F = np.zeros((n, p), np.float32), np.full((n, p), -1, np.float32), np.full((n, p), -1, np.int8)
        ell = np.zeros(n)
        dirty = np.ones((n, p), np.uint8)
        update_log_likelihood(Df, loc, np.arange(p), z, s, e, lpi, o_hat, anc, C, Q, F, ell, PRM.tail_weight,
                              PRM.occluder_rate, PRM.tail_weight / PRM.max_depth, True, dirty, 1.0, cm, cv)
        assert not dirty.any()
        return ell, Q, F

    cm, cv = np.ones((k, p), np.uint8), np.zeros(k, np.uint8)
    ell, Q, F = run(cm, cv)
    d = D.min(axis=1).astype(np.float64)
    pv = visible_likelihood(z[None], d, PRM)
    po = occluded_likelihood(z[None], d, PRM)
    lik = pv * (1 - o_hat) + po * o_hat
    ref = np.where(np.isfinite(d), np.log(lik) - np.log(occluded_likelihood(z, np.inf, PRM))[None], 0.0)
    assert np.allclose(ell, ref.sum(axis=1), rtol=1e-5)
    post, vis = finish_occlusion(Q, F, o_hat, anc, k)
    ref_post = np.where(np.isfinite(d), po * o_hat / lik, o_hat)
    assert np.allclose(post, ref_post, atol=1e-5)
    front = np.argmin(D, axis=1)
    for o in range(k):
        sel = np.isfinite(d[0]) & (front[0] == o)
        assert vis[0, o] == pytest.approx(float(np.mean(1 - ref_post[0, sel])), abs=1e-5)
    # a part behind the observed surface becomes more likely occluded; one matching it, less
    assert np.all(post[:, 30] > o_hat[:, 30])
    assert np.all(post[:, 5] < o_hat[:, 5])
    # colour masks: outside part 0's blob the pixel counts as occluded (ô = 1) where part 0 is front-most
    cv[0] = 1
    cm[0, :10] = 0
    ell2, _, _ = run(cm, cv)
    oh = o_hat.astype(np.float64)
    oh[:, :10] = 1.0
    lik2 = pv * (1 - oh) + po * oh
    ref2 = np.where(np.isfinite(d), np.log(lik2) - np.log(occluded_likelihood(z, np.inf, PRM))[None], 0.0)
    ref2[:, :10] = np.minimum(ref2[:, :10], 0.0)  # a forced-occluded pixel is no evidence for the part (cap at 0)
    assert np.allclose(ell2, ref2.sum(axis=1), rtol=1e-5)
    assert ell2[0] < ell[0]  # the part matches the depth there, so masking it out costs likelihood
    # outside its blob, a part hidden behind a nearer surface gains nothing there (without the cap the truncated
    # occluder density would reward it), while a part floating in front of the observed surface is still penalised
    cm2, cv2 = np.ones((k, p), np.uint8), np.zeros(k, np.uint8)
    cv2[1] = 1
    cm2[1, 30] = 0
    saved = Df.copy()
    Df[:, loc[0, 30]] = np.inf
    Df[:, loc[1, 30]] = np.inf
    ell_none, _, _ = run(cm2, cv2)  # pixel 30 uncovered: contributes 0
    Df[:, loc[1, 30]] = np.float32(z[30] + 0.1)  # part 1 alone, 10 cm behind the observed depth
    ell_behind, _, _ = run(cm2, cv2)
    Df[:, loc[1, 30]] = np.float32(z[30] - 0.1)  # part 1 alone, 10 cm in front of it
    ell_front, _, _ = run(cm2, cv2)
    Df[:] = saved
    assert np.allclose(ell_behind, ell_none, rtol=1e-6)
    assert np.all(ell_front < ell_none - 1.0)


# ---------------------------------------------------------------- resampling (spec 4.4)
def test_kl_bounds():
    n = 50
    assert kl_from_uniform(np.full(n, 1 / n)) == pytest.approx(0.0, abs=1e-12)
    w = np.zeros(n)
    w[3] = 1
    assert kl_from_uniform(w) == pytest.approx(math.log(n))


def test_systematic_resampling_counts_and_distribution():
    rng = np.random.default_rng(1)
    n = 200
    w = rng.gamma(0.5, size=n)
    w /= w.sum()
    idx = systematic_resample(w, rng)
    counts = np.bincount(idx, minlength=n)
    # low-variance property: every count is floor or ceil of N·w_i
    assert np.all(counts >= np.floor(n * w) - 1e-9) and np.all(counts <= np.ceil(n * w) + 1e-9)
    assert counts.sum() == n
    # statistical test: the resampled (uniform-weight) mean of a function equals the weighted mean
    x = rng.normal(size=n)
    means = [x[systematic_resample(w, rng)].mean() for _ in range(400)]
    se = np.std(means) / math.sqrt(len(means))
    assert abs(np.mean(means) - float(w @ x)) < 4 * se + 1e-3
    # the printed Algorithm 3 bug (one u for all) would copy one index only
    assert len(np.unique(idx)) > 20


def test_normalize_log_weights_stable():
    w = normalize_log_weights(np.array([-1000.0, -1001.0, -5000.0]))
    assert w.sum() == pytest.approx(1.0)
    assert w[0] / w[1] == pytest.approx(math.e)


# ---------------------------------------------------------------- rendering
def test_box_renderer_face_on_depth_and_occlusion():
    intr = Intrinsics.default()
    front = Pose([0, 0, 0.5], [0, 0, 0, 1])
    back = Pose([0.0, 0.0, 0.8], [0, 0, 0, 1])
    d = render_box_depth(intr, [back, front], [(0.2, 0.2, 0.2), (0.036, 0.036, 0.036)])
    assert d[240, 320] == pytest.approx(0.5 - 0.018, abs=1e-6)  # the nearer cube's front face
    assert d[240, 320 + 60] == pytest.approx(0.7, abs=1e-6)  # the big box beside it
    assert not np.isfinite(d[10, 10])
    # silhouette width of the cube: 0.036 m at z = 0.482 m → 0.036·525/0.482 ≈ 39 px
    row = np.isfinite(d[240]) & (d[240] < 0.6)
    assert abs(int(row.sum()) - 39) <= 1


@pytest.mark.parametrize("lattice", [1, 2, 3])
def test_mesh_renderer_matches_box_renderer(tmp_path, lattice):
    """Mesh rasterisation at the likelihood grid, and on every ``lattice``-th grid pixel (large parts whose
    likelihood pixels were thinned): exact depth on that lattice."""
    intr = Intrinsics.default()
    path = tmp_path / "cube.stl"
    import trimesh

    trimesh.creation.box(extents=(0.04, 0.03, 0.05)).export(path)
    part = PartSpec("m", box=None, mesh=str(path))
    model = MeshModel.from_part(part)
    pose = Pose.from_rotvec([0.3, -0.4, 0.2], [0.02, -0.01, 0.6])
    f = 4
    ref = render_box_depth(intr, [pose], [(0.04, 0.03, 0.05)], downsample=f)
    off = (f - 1) // 2
    hh, ww = ref.shape
    gj, gi = np.meshgrid(np.arange(hh), np.arange(ww), indexing="ij")
    gi, gj = gi.ravel().astype(np.int64), gj.ravel().astype(np.int64)
    out = np.full((1, gi.size), np.inf, np.float32)
    loc = np.arange(gi.size, dtype=np.int64).reshape(1, -1)
    render_mesh_at_pixels(pose.R[None, None], pose.t[None, None], model.vertices, model.faces, 0,
                          np.zeros(1, np.int64), gi, gj, np.arange(gi.size, dtype=np.int64), float(f), float(off),
                          intr.fx, intr.fy, intr.cx, intr.cy, out, loc, np.zeros((1, gi.size), np.uint8), lattice)
    mesh_d = out[0].reshape(hh, ww)
    on = ((gi % lattice == 0) & (gj % lattice == 0)).reshape(hh, ww)
    both = np.isfinite(ref) & np.isfinite(mesh_d) & on
    assert both.sum() > 20 / lattice**2
    assert np.abs(mesh_d[both] - ref[both]).max() < 1e-4
    # silhouettes agree except possibly at exact edge pixels
    assert np.sum((np.isfinite(ref) != np.isfinite(mesh_d)) & on) <= 0.1 * np.isfinite(ref[on]).sum()


def test_bad_mesh_gives_clear_error(tmp_path):
    bad = tmp_path / "broken.obj"
    bad.write_text("this is not a mesh\n")
    with pytest.raises((ValueError, FileNotFoundError), match="broken.obj"):
        MeshModel.from_part(PartSpec("x", box=None, mesh=str(bad)))
    with pytest.raises(FileNotFoundError, match="missing.stl"):
        MeshModel.from_part(PartSpec("y", box=None, mesh=str(tmp_path / "missing.stl")))


# ---------------------------------------------------------------- penalties
def test_box_intersection_with_contact_tolerance():
    a = CUBE_EDGE
    size = (a, a, a)
    p0 = Pose([0, 0, 0.5], [0, 0, 0, 1])
    touching = Pose([a, 0, 0.5], [0, 0, 0, 1])
    slightly_in = Pose([a - 0.001, 0, 0.5], [0, 0, 0, 1])
    deep = Pose([a - 0.01, 0.005, 0.5], [0, 0, 0, 1])
    assert not boxes_intersect(p0, size, touching, size, tol=0.002)
    assert not boxes_intersect(p0, size, slightly_in, size, tol=0.002)
    assert boxes_intersect(p0, size, deep, size, tol=0.002)
    # a 45°-rotated cube: its edge reaches a·√2/2 from the centre
    rot = Pose.from_rotvec([0, 0, math.pi / 4], [a / 2 + a * math.sqrt(2) / 2 - 0.004, 0, 0.5])
    assert boxes_intersect(p0, size, rot, size, tol=0.002)
    rot_far = Pose.from_rotvec([0, 0, math.pi / 4], [a / 2 + a * math.sqrt(2) / 2 + 0.001, 0, 0.5])
    assert not boxes_intersect(p0, size, rot_far, size, tol=0.0)
    # separated only along a cross-product axis (edge-edge case)
    r1 = Pose.from_rotvec([math.pi / 4, 0, 0], [0, 0, 0.5])
    r2 = Pose.from_rotvec([0, math.pi / 4, 0], [0, 0, 0.5 + a * math.sqrt(2) + 0.002])
    assert not boxes_intersect(r1, size, r2, size)


def test_table_penalty():
    n = np.array([0.0, -1.0, 0.0])  # table normal up (camera y down)
    offset = 0.3  # plane y = 0.3
    cube = PartSpec.cube("c")
    R = np.eye(3)[None, None]
    t_rest = np.array([[[0.0, 0.3 - CUBE_EDGE / 2, 0.8]]])
    t_sunk = t_rest + np.array([0, 0.003, 0])
    h = lowest_heights(np.concatenate([R, R]), np.concatenate([t_rest, t_sunk]), [cube.vertices()], n, offset)
    assert h[0] == pytest.approx(0.0, abs=1e-12)
    assert h[1] == pytest.approx(-0.003, abs=1e-12)
    pen = table_log_penalty(h, 1000.0)
    assert pen[0] == 0.0
    assert math.exp(pen[1]) == pytest.approx(math.exp(-3.0))
    assert math.exp(float(table_log_penalty(np.array([-0.0023]), 1000.0)[0])) == pytest.approx(0.1, rel=0.01)


# ---------------------------------------------------------------- connection particles (Algorithm 6)
def test_connection_particles_force_relative_pose():
    rng = np.random.default_rng(2)
    n = 10
    names = ["a", "b", "c"]
    p = rng.normal(0, 0.1, (n, 3, 3))
    R = rotvec_to_matrix(rng.normal(0, 0.5, (n * 3, 3))).reshape(n, 3, 3, 3)
    rel_ab = Pose.from_rotvec([0, math.pi / 2, 0], [CUBE_EDGE, 0, 0])
    rel_bc = Pose([0, CUBE_EDGE, 0], [0, 0, 0, 1])
    hints = [ConnectionHint("a", "b", rel_ab, 6), ConnectionHint("b", "c", rel_bc, 4)]
    conns = resolve_hints(hints, names, n, 0.5)
    assert [c.n_k for c in conns] == [5, 4]  # overflow rule: N_k ≤ 0.5·N
    p0 = p.copy()
    changed = apply_connections(p, R, conns)
    for j in range(5):
        pa, pb = Pose.from_rt(R[j, 0], p[j, 0]), Pose.from_rt(R[j, 1], p[j, 1])
        rel = pa.inverse() @ pb
        assert np.allclose(rel.t, rel_ab.t, atol=1e-9)
        assert rel.rotation_error(rel_ab) < 1e-6
    for j in range(4):
        pb, pc = Pose.from_rt(R[j, 1], p[j, 1]), Pose.from_rt(R[j, 2], p[j, 2])
        assert np.allclose((pb.inverse() @ pc).t, rel_bc.t, atol=1e-9)
    # odd (1-based) particles keep the first part; free particles untouched
    assert np.allclose(p[0, 0], p0[0, 0]) and np.allclose(p[5:, :], p0[5:, :])
    assert changed[:5].any() and not changed[5:].any()
    with pytest.raises(ValueError, match="unknown part"):
        resolve_hints([ConnectionHint("a", "zzz", rel_ab, 3)], names, n, 0.5)


def test_unlocked_hints_do_not_force_hidden_parts():
    """Visibility gate (hint_min_visibility): an unlocked hint leaves a part that is not forceable (hidden)
    alone; a locked hint forces it anyway."""
    rng = np.random.default_rng(5)
    n = 6
    p = rng.normal(0, 0.1, (n, 2, 3))
    R = np.broadcast_to(np.eye(3), (n, 2, 3, 3)).copy()
    rel = Pose([CUBE_EDGE, 0, 0], [0, 0, 0, 1])
    hidden_b = np.array([True, False])  # a visible, b hidden
    for locked in (False, True):
        conns = resolve_hints([ConnectionHint("a", "b", rel, 4, locked)], ["a", "b"], n, 1.0)
        q, Rq = p.copy(), R.copy()
        changed = apply_connections(q, Rq, conns, hidden_b)
        if locked:
            assert changed[0, 1] and np.allclose(q[0, 1], q[0, 0] + [CUBE_EDGE, 0, 0])
        else:
            assert not changed[:, 1].any() and np.allclose(q[:, 1], p[:, 1])
        # the backward pass moves the visible first part onto the hidden second part in both cases
        assert changed[1, 0] and np.allclose(q[1, 0], q[1, 1] - [CUBE_EDGE, 0, 0])


# ---------------------------------------------------------------- motion model
def test_rotation_mean_and_propagation():
    rng = np.random.default_rng(3)
    base = Pose.from_rotvec([0.4, -0.2, 1.0], [0, 0, 0]).R
    small = rotvec_to_matrix(rng.normal(0, 0.05, (500, 3)))
    Rs = small @ base
    w = np.full(500, 1 / 500)
    Rm = mean_rotation(Rs, w)
    assert Pose.from_rt(Rm, np.zeros(3)).rotation_error(Pose.from_rt(base, np.zeros(3))) < 0.01
    # sign-flipped quaternions do not break the mean (q and −q are the same rotation)
    assert np.allclose(mean_rotation(np.stack([base, base]), np.array([0.5, 0.5])), base, atol=1e-9)
    # (4.26): v = k_v v + b u + w; r = r + v
    p_ref = np.zeros((1, 3))
    v_prev = np.array([[0.01, 0, 0, 0, 0, 0.1]])
    p, R, v = propagate(p_ref, np.eye(3)[None], v_prev, np.array([0.0, 0.02, 0.0]), np.zeros((1, 6)), 0.5, 0.3)
    assert np.allclose(v[0], [0.005, 0.006, 0, 0, 0, 0.05])
    assert np.allclose(p[0], [0.005, 0.006, 0])
    assert np.allclose(R[0], rotvec_to_matrix(np.array([[0, 0, 0.05]]))[0])


# ---------------------------------------------------------------- configuration
def test_presets_and_config_files(tmp_path):
    e1 = TrackerConfig.preset("seed-exp1")
    assert (e1.b, e1.k_v, e1.sigma_v, e1.sigma_w, e1.kl_max, e1.n_max, e1.score_k) == (0.5, 0.3, 0.01, 0.1, 0.5, 12, 7)
    e23 = TrackerConfig.preset("seed-exp23")
    assert (e23.b, e23.k_v, e23.sigma_v, e23.sigma_w, e23.kl_max, e23.m_p) == (0.3, 0.2, 0.005, 0.05, 1.0, 0.01)
    assert e23.n_particles == 225 and e23.lambda_i == 0.01 and e23.lambda_h == 1000.0 and e23.downsample == 8
    assert set(PRESETS) >= {"seed-exp1", "seed-exp23", "default"}
    y = tmp_path / "t.yaml"
    y.write_text("preset: seed-exp1\nn_particles: 100\n")
    c = TrackerConfig.load(y)
    assert c.n_particles == 100 and c.b == 0.5
    t = tmp_path / "t.toml"
    t.write_text("[tracker]\nsigma_v = 0.002\n")
    assert TrackerConfig.load(t).sigma_v == 0.002
    bad = tmp_path / "bad.yaml"
    bad.write_text("n_particle: 3\n")
    with pytest.raises(ValueError, match="unknown setting"):
        TrackerConfig.load(bad)
    bad.write_text("n_particles: -3\n")
    with pytest.raises(ValueError, match="bad.yaml"):
        TrackerConfig.load(bad)
    with pytest.raises(ValueError, match="unknown tracker preset"):
        TrackerConfig.preset("nope")


# ---------------------------------------------------------------- ICP refinement
def test_icp_refinement_recovers_small_offset():
    from tracker.refine.icp_refinement import PartSurfaceModel, icp_refine, part_points

    intr = Intrinsics.default()
    part = PartSpec.cube("c")
    true = Pose.from_rotvec([0.5, 0.3, 0.1], [0.01, 0.02, 0.6])
    depth = render_box_depth(intr, [true], [part.box]).astype(np.float32)
    depth[~np.isfinite(depth)] = np.nan
    start = Pose.from_rt(Pose.from_rotvec([0.0, 0.05, 0.0], [0, 0, 0]).R @ true.R, true.t + [0.003, -0.002, 0.002])
    pts = part_points(depth, intr, start, part.bounding_radius() + 0.005, None, None, stride=2)
    assert pts.shape[0] > 100
    ref = icp_refine(PartSurfaceModel(part), pts, start, iterations=15)
    assert ref is not None
    assert ref.translation_error(true) < 0.001
    assert math.degrees(ref.rotation_error(true)) < 1.0
    assert icp_refine(PartSurfaceModel(part), pts[:5], start) is None  # too few points


def test_icp_surface_model_is_deterministic():
    """Two models of the same part sample the same surface points (trimesh needs an explicit seed)."""
    from tracker.refine.icp_refinement import PartSurfaceModel

    part = PartSpec.cube("c")
    a, b = PartSurfaceModel(part), PartSurfaceModel(part)
    assert np.array_equal(a.points, b.points) and np.array_equal(a.normals, b.normals)
    assert not np.array_equal(a.points, PartSurfaceModel(part, seed=1).points)


def test_penalty_terms_kept_per_part_equal_the_full_penalty():
    """The coordinate passes' penalties, recomputed only for the parts a pass moved and reordered with a resampling,
    equal the penalties computed from scratch (colour term, intersections, table)."""
    from tracker.filter.particle_filter import MultiObjectTracker
    from tracker.filter.weigh import PenaltyTerms, log_penalties

    intr = Intrinsics(640, 480, 600.0, 600.0, 320.0, 240.0)
    parts = [PartSpec.cube(c, c) for c in ("red", "green", "blue", "yellow")]
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=60, color_likelihood_px=6.0, lambda_h=20.0)
    trk = MultiObjectTracker(parts, intr, cfg, seed=0)
    rng = np.random.default_rng(4)
    n, k = 60, len(parts)
    # cubes side by side on a plane 0.5 m away, close enough that noisy particles interpenetrate
    base = np.array([[x, 0.0, 0.5] for x in (-0.06, -0.02, 0.02, 0.06)])
    p = base[None] + rng.normal(0.0, 0.004, (n, k, 3))
    R = np.stack([rotvec_to_matrix(rng.normal(0.0, 0.15, (n, 3))) for _ in range(k)], axis=1)
    plane = (np.array([0.0, -1.0, 0.0]), 0.024)  # table under the cubes (y down in the camera frame)
    trk._color_targets = [(0, np.array([300.0, 240.0]), 0.8), (2, np.array([360.0, 245.0]), 1.0)]
    terms = PenaltyTerms(trk, plane)
    for step in range(12):
        moved = {int(rng.integers(k))}
        if step % 3 == 2:
            moved.add(int(rng.integers(k)))
        for i in moved:
            p[:, i] += rng.normal(0.0, 0.002, (n, 3))
            R[:, i] = rotvec_to_matrix(rng.normal(0.0, 0.05, (n, 3))) @ R[:, i]
        got = terms.total(p, R, None if step == 0 else moved)
        want = log_penalties(trk, p, R, plane)
        assert np.allclose(got, want, rtol=0.0, atol=1e-9)  # the same sums (einsum may round a last bit apart)
        if step % 4 == 1:
            idx = np.sort(rng.integers(0, n, n))
            p, R = p[idx], R[idx]
            terms.take(idx)
    # the last scene has particles with and without each kind of penalty
    from tracker.filter.penalties import intersection_log_penalty

    inter = intersection_log_penalty(R, p, trk.center, trk.half, trk.pairs, cfg.contact_tolerance, cfg.lambda_i)
    sink = table_log_penalty(lowest_heights(R, p, trk.hulls, *plane), cfg.lambda_h, cfg.table_tolerance)
    assert np.any(inter < 0) and np.any(inter == 0)
    assert np.any(sink < 0) and np.any(sink == 0)
