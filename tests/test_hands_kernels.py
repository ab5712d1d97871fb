"""The hand tracker's compiled kernels against the plain numpy forms they replace (same values, bit for bit)."""

from __future__ import annotations

import numpy as np

from tracker.hands.motion_clusters import MotionClusters, _gather, _nearest


def _flow_and_mask(seed: int, h: int = 37, w: int = 53) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    flow = rng.normal(0.0, 3.0, (h, w, 2)).astype(np.float32)
    flow[rng.random((h, w)) < 0.1] = np.round(flow[rng.random((h, w)) < 0.1][:1])  # repeated vectors: ties
    mask = (rng.random((h, w)) < 0.4).astype(np.uint8)
    return flow, mask


def test_gather_is_boolean_indexing():
    for seed in range(3):
        flow, mask = _flow_and_mask(seed)
        got = _gather(flow, mask)
        assert got.dtype == np.float32
        np.testing.assert_array_equal(got, flow[mask.astype(bool)])
    assert _gather(flow, np.zeros_like(mask)).shape == (0, 2)


def test_nearest_is_numpy_argmin_of_float32_distances():
    rng = np.random.default_rng(4)
    fit = rng.normal(0.0, 2.0, (200, 2)).astype(np.float32)
    prev = fit[[3, 3, 50, 120]].copy()  # two equal centroids: the first wins
    fit[7] = np.nan  # a NaN distance wins for every centroid: index 0, as numpy's argmin
    prev[2, 1] = np.nan
    want = np.argmin(((fit[:, None, :] - prev[None]) ** 2).sum(-1), axis=1).astype(np.int32)
    got = _nearest(fit, prev)
    np.testing.assert_array_equal(got, want)
    assert got[7] == 0 and (np.delete(got, 7) == 2).all()  # the first NaN distance wins, as in numpy
    prev[2, 1] = 0.0
    want = np.argmin(((fit[:, None, :] - prev[None]) ** 2).sum(-1), axis=1).astype(np.int32)
    np.testing.assert_array_equal(_nearest(fit, prev), want)
    assert set(want.tolist()) >= {0, 2, 3}


def _segment_numpy(mc: MotionClusters, flow: np.ndarray, mask: np.ndarray, key: str):
    """The segmentation as first written (numpy gather, numpy warm start, labels filled with −1 first)."""
    import cv2

    from tracker.hands.motion_clusters import ATTEMPTS, MAX_FIT, MAX_ITER, _assign

    h, w = mask.shape
    labels = np.full((h, w), -1, np.int32)
    cent = np.full((mc.n_clusters, 2), np.nan)
    sel = mask.astype(bool)
    vec = flow[sel].astype(np.float32)
    n = len(vec)
    k = min(mc.n_clusters, n)
    fit = vec if n <= MAX_FIT else vec[mc.rng.choice(n, MAX_FIT, replace=False)]
    cv2.setRNGSeed(int(mc.rng.integers(1 << 30)))
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, MAX_ITER, 0.01)
    prev = mc._prev.get(key)
    if prev is not None and len(prev) == k:
        init = np.argmin(((fit[:, None, :] - prev[None]) ** 2).sum(-1), axis=1).astype(np.int32)[:, None]
        _, _, centers = cv2.kmeans(fit, k, init, crit, 1, cv2.KMEANS_USE_INITIAL_LABELS)
    else:
        _, _, centers = cv2.kmeans(fit, k, None, crit, ATTEMPTS, cv2.KMEANS_PP_CENTERS)
    counts, su, sv = _assign(flow, sel, np.asarray(centers, np.float32), labels)
    ok = counts > 0
    cent[:k][ok] = np.stack([su[ok] / counts[ok], sv[ok] / counts[ok]], axis=1)
    mc._prev[key] = np.asarray(centers, np.float32)
    return labels, cent


def test_segmentation_equals_the_numpy_form_over_warm_started_frames():
    a, b = MotionClusters(4, seed=3), MotionClusters(4, seed=3)
    for frame in range(6):
        flow, mask = _flow_and_mask(10 + frame, 60, 70)  # 60·70·0.4 ≈ 1700 vectors > MAX_FIT: subsampled fit
        la, ca = a.segment(flow, mask, "f1")
        lb, cb = _segment_numpy(b, flow, mask, "f1")
        np.testing.assert_array_equal(la, lb)
        np.testing.assert_array_equal(ca, cb)
        assert (la[mask == 0] == -1).all() and (la[mask == 1] >= 0).all()


def _invert_numpy(f: np.ndarray) -> np.ndarray:
    """:func:`tracker.hands.flow.invert` as first written (the fill rounds in numpy)."""
    import cv2

    from tracker.hands.flow import _splat

    h, w = f.shape[:2]
    out = np.zeros((h, w, 2), np.float32)
    filled = _splat(np.ascontiguousarray(f, np.float32), out)
    if not filled.any():
        return out
    empty = ~filled
    wgt = filled.astype(np.float32)
    for _ in range(4):
        if not empty.any():
            break
        num = cv2.blur(out * wgt[..., None], (7, 7))
        den = cv2.blur(wgt, (7, 7))
        fill = empty & (den > 1e-6)
        out[fill] = num[fill] / den[fill][:, None]
        wgt[fill] = 1.0
        empty &= ~fill
    if empty.any():
        out[empty] = out[~empty].mean(axis=0)
    return out


def test_flow_inversion_equals_the_numpy_form():
    from tracker.hands.flow import invert

    rng = np.random.default_rng(5)
    for scale in (0.5, 3.0, 12.0):  # few holes; many holes (several fill rounds); holes left after four rounds
        f = (rng.normal(0.0, scale, (41, 57, 2)) + np.float32([1.5, -0.5])).astype(np.float32)
        np.testing.assert_array_equal(invert(f), _invert_numpy(f))
    f = np.full((20, 30, 2), 50.0, np.float32)  # everything lands outside: nothing filled
    np.testing.assert_array_equal(invert(f), _invert_numpy(f))
    f = np.zeros((40, 40, 2), np.float32)
    f[:, :, 0] = 30.0
    f[:2, :2] = 0.0  # four pixels filled in one corner: the fill does not reach the far side in four rounds
    np.testing.assert_array_equal(invert(f), _invert_numpy(f))


def test_flow_scaling_equals_the_numpy_broadcast():
    from tracker.hands.flow import _scaled

    rng = np.random.default_rng(6)
    f = rng.normal(0.0, 4.0, (33, 47, 2)).astype(np.float32)
    sx, sy = 47 / 23.0, 33 / 16.0
    want = f * np.float32([sx, sy])
    got = _scaled(f.copy(), np.float32(sx), np.float32(sy))
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, want)


def _blob_scene():
    """A colour mask with two blobs (one cut into two touching pieces' worth of area) and its components, a flow
    field moving them (2, 1) px, and the flow's motion labels: the inputs of the particle filter's propagation."""
    import cv2

    mask = np.zeros((90, 120), np.uint8)
    cv2.ellipse(mask, (40, 45), (18, 25), 0, 0, 360, 1, -1)
    cv2.rectangle(mask, (80, 20), (105, 60), 1, -1)
    n, cc, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=4, ltype=cv2.CV_32S)
    boxes = np.stack([stats[:, 0], stats[:, 1], stats[:, 0] + stats[:, 2] - 1, stats[:, 1] + stats[:, 3] - 1], 1)
    flow = np.zeros((90, 120, 2), np.float32)
    flow[..., 0], flow[..., 1] = 2.0, 1.0
    flow += np.random.default_rng(7).normal(0, 0.3, flow.shape).astype(np.float32)
    labels = np.where(mask > 0, 0, -1).astype(np.int32)
    cut = np.zeros(n, bool)
    cut[0] = True
    return mask, cc, int(n - 1), stats[:, 4].astype(np.int64), boxes.astype(np.int64), cut, flow, labels


def test_propagation_reuses_the_section6_test_of_equal_particles_without_changing_a_result():
    from tracker.hands.box_stats import transition_stats_of_states
    from tracker.hands.particle_filter import _propagate

    mask, cc, n_comp, area, boxes, cut, flow, labels = _blob_scene()
    rng = np.random.default_rng(8)
    base = np.array([[40.0, 45.0, 36.0, 50.0, 2.0, 1.0], [92.0, 40.0, 25.0, 40.0, 0.0, 0.0],
                     [40.5, 44.0, 20.0, 20.0, 1.0, 0.0], [60.0, 45.0, 30.0, 30.0, 0.0, 0.0]])  # fmt: skip
    parts = base[rng.integers(0, len(base), 24)]  # many exact copies, as after resampling
    stats = transition_stats_of_states(parts, 0.0, 0.0, mask, flow, flow, labels, labels, 4, 64)
    cent = np.full((2, 4, 2), np.nan)
    cent[:, 0] = (2.0, 1.0)
    u3 = rng.random((len(parts), 3))
    z = rng.standard_normal((len(parts), 3, 2))
    args = (cc, n_comp, area, boxes, cut, 0.0, 0.0, 120.0, 90.0)
    out, det = _propagate(parts, stats, cent, *args, u3, z, 10, 0.8, 1.0, 1.0, 1.0)
    assert det.any() and not det.all()  # both kinds of transition happen
    for i in range(len(parts)):  # one particle at a time: nothing to reuse
        o, d = _propagate(parts[i : i + 1], stats[i : i + 1], cent, *args, u3[i : i + 1], z[i : i + 1], 10, 0.8, 1.0,
                          1.0, 1.0)  # fmt: skip
        np.testing.assert_array_equal(o[0], out[i])
        assert d[0] == det[i]


def test_wrist_cut_per_particle_equals_the_python_form():
    from tracker.hands.box_stats import box_of
    from tracker.hands.palm_cut import ANCHOR_INSIDE, anchor_state, holds_anchor
    from tracker.hands.particle_filter import _take_anchor

    rng = np.random.default_rng(9)
    anc = np.array([30.0, 40.0, 55.0, 70.0])
    prev = np.column_stack([rng.uniform(20, 60, 40), rng.uniform(30, 80, 40), rng.uniform(10, 60, (40, 2)),
                            rng.normal(0, 2, (40, 2))])  # fmt: skip
    new = prev + rng.normal(0, 3, prev.shape)
    new[::3, 2:4] = (80.0, 90.0)  # boxes over the whole arm: they hold the anchor
    new[1::3, 2:4] = (30.0, 30.0)
    det = rng.random(40) < 0.6
    want_new, want_det = new.copy(), det.copy()
    for i in range(40):
        if want_det[i] and not holds_anchor(box_of(*want_new[i, :4]), anc):
            continue
        want_new[i] = anchor_state(anc, (prev[i, 0], prev[i, 1]))
        want_det[i] = True
    got_new, got_det = new.copy(), det.copy()
    _take_anchor(got_new, got_det, prev, anc, ANCHOR_INSIDE)
    np.testing.assert_array_equal(got_new, want_new)
    np.testing.assert_array_equal(got_det, want_det)
    assert 0 < int((det & (got_new[:, 0] == 42.5)).sum()) < int(det.sum())  # some mode particles kept, some taken


def test_part_window_equals_the_numpy_form():
    from tracker.hands.loop import _window

    rng = np.random.default_rng(10)
    fx, fy, cx, cy, W, H = 600.0, 610.0, 319.5, 239.5, 640, 480
    for _ in range(200):
        pts = rng.normal(0, 0.05, (8, 3)) + (rng.uniform(-0.5, 0.5), rng.uniform(-0.4, 0.4), rng.uniform(-0.05, 1.0))
        ok, u0, v0, u1, v1 = _window(pts, fx, fy, cx, cy, W, H)
        if pts[:, 2].min() <= 1e-3:
            assert not ok
            continue
        us, vs = fx * pts[:, 0] / pts[:, 2] + cx, fy * pts[:, 1] / pts[:, 2] + cy
        want = (max(int(np.floor(us.min())) - 1, 0), max(int(np.floor(vs.min())) - 1, 0),
                min(int(np.ceil(us.max())) + 2, W), min(int(np.ceil(vs.max())) + 2, H))  # fmt: skip
        assert ok == (want[2] > want[0] and want[3] > want[1])
        if ok:
            assert (u0, v0, u1, v1) == want


def test_cropped_components_equal_the_whole_mask_labelling():
    import cv2

    from tracker.hands.palm_cut import cropped_components

    rng = np.random.default_rng(11)
    for trial in range(40):
        mask = np.zeros((61, 83), np.uint8)
        y, x = int(rng.integers(0, 40)), int(rng.integers(0, 60))  # odd and even corners
        h, w = int(rng.integers(1, 61 - y)), int(rng.integers(1, 83 - x))
        mask[y : y + h, x : x + w] = rng.random((h, w)) < (0.3 if trial % 2 else 0.6)  # many small components
        n, lab, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=4, ltype=cv2.CV_32S)
        cn, clab, cstats, (x0, y0) = cropped_components(mask)
        assert cn == n and x0 % 2 == 0 and y0 % 2 == 0
        np.testing.assert_array_equal(cstats[1:], stats[1:])
        full = np.zeros_like(lab)
        full[y0 : y0 + clab.shape[0], x0 : x0 + clab.shape[1]] = clab
        np.testing.assert_array_equal(full, lab)
    cn, clab, cstats, _ = cropped_components(np.zeros((10, 12), np.uint8))
    assert cn == 1 and not clab.any()


def test_skin_log_densities_on_the_colour_grid_equal_the_row_form():
    from tracker.hands.skin_model import _GRID, Gmm2D, SkinModel

    model = SkinModel.load()
    rng = np.random.default_rng(12)
    px = np.clip(rng.normal((190, 140, 110), 20, (3000, 3)), 0, 255).astype(np.uint8)
    adapted = model.adapted(px, max_shift=1.0).skin
    random = Gmm2D(np.array([0.2, 0.5, 0.3]), rng.uniform(60, 200, (3, 2)), np.array([[[90.0, 20.0], [20.0, 40.0]],
                   [[10.0, -3.0], [-3.0, 8.0]], [[400.0, 0.0], [0.0, 300.0]]]))  # fmt: skip
    for g in (model.skin, model.background, adapted, random):
        want, got = g.logpdf(_GRID), g.grid_logpdf()
        np.testing.assert_array_equal(got, want)
        assert np.array_equal(np.signbit(got), np.signbit(want))


def test_part_surface_exclusion_equals_the_numpy_form():
    from tracker.geometry.camera import Intrinsics
    from tracker.geometry.parts import PartSpec
    from tracker.geometry.pose import Pose
    from tracker.hands.loop import _box_rays, _mark_part_surface, box_part_depth

    intr = Intrinsics(fx=600.0, fy=600.0, cx=319.5, cy=239.5, width=640, height=480)
    part = PartSpec.cube("red", "red")
    pose = Pose.from_rotvec(np.array([0.3, -0.5, 0.2]), np.array([0.02, -0.01, 0.45]))
    u, v = np.arange(250, 390, 2), np.arange(170, 310, 2)
    zr = box_part_depth(part, pose, intr, u, v)
    rng = np.random.default_rng(13)
    for dtype in (np.float32, np.float64):
        z = np.full((120, 160), 0.6, dtype)
        win = z[40:110, 60:130]
        win[:] = np.where(np.isfinite(zr), zr, 0.6) + rng.choice([-0.02, -0.01, -0.0100001, 0.0, 0.01], zr.shape)
        win[rng.random(zr.shape) < 0.05] = np.nan
        want = np.zeros(z.shape, bool)
        with np.errstate(invalid="ignore"):
            want[40:110, 60:130] = np.isfinite(zr) & (win >= zr - 0.01)
        got = np.zeros(z.shape, bool)
        half, R, o, x, y = _box_rays(part, pose, intr, u, v)
        _mark_part_surface(R, o, half, x, y, z[::1, ::1], 60, 40, np.float32(0.01), got)
        np.testing.assert_array_equal(got, want)
        assert 0 < want.sum() < np.isfinite(zr).sum()


def test_mask_upsampling_equals_opencv_nearest_on_the_whole_image():
    import cv2

    from tracker.hands.tracker import HandTracker, HandTrackerConfig

    rng = np.random.default_rng(14)
    for s, (W, H) in ((2, (640, 480)), (2, (641, 481)), (3, (640, 480)), (1, (320, 240))):
        tr = HandTracker(HandTrackerConfig(scale=s))
        tr.full_size = (W, H)
        h, w = H // s, W // s
        for _ in range(5):
            small = np.zeros((h, w), np.uint8)
            y, x = int(rng.integers(0, h - 5)), int(rng.integers(0, w - 5))
            small[y : y + 40, x : x + 60] = rng.random(small[y : y + 40, x : x + 60].shape) < 0.5
            up = small if s == 1 else cv2.resize(small, (w * s, h * s), interpolation=cv2.INTER_NEAREST)
            want = np.zeros((H, W), bool)
            want[: min(H, h * s), : min(W, w * s)] = up[:H, :W].astype(bool)
            np.testing.assert_array_equal(tr._upsampled(small), want)
        assert not tr._upsampled(np.zeros((h, w), np.uint8)).any()


def test_roi_bounds_equal_the_python_loop():
    from tracker.hands.track_boxes import state_box
    from tracker.hands.tracker import _roi_bounds

    rng = np.random.default_rng(15)
    for margin in (12.0, 17.25, 33.5):
        states = np.column_stack([rng.uniform(-20, 340, 30), rng.uniform(-20, 260, 30), rng.uniform(2, 90, (30, 2)),
                                  rng.normal(0, 3, (30, 2))])  # fmt: skip
        states[0, :4] = (-3.3, -2.6, 5.0, 4.0)  # a box past the image corner
        x0, y0, x1, y1 = 320, 240, 0, 0
        for p in states:
            u0, v0, u1, v1 = state_box(p)
            x0, y0 = min(x0, int(u0 - margin)), min(y0, int(v0 - margin))
            x1, y1 = max(x1, int(u1 + margin) + 1), max(y1, int(v1 + margin) + 1)
        assert _roi_bounds(states, margin, 320, 240, 0, 0) == (x0, y0, x1, y1)
        assert x0 < 0 and y0 < 0  # boxes past the image edge: int() truncates towards zero there


def test_table_plane_marking_equals_the_numpy_form():
    from tracker.hands.loop import _near_plane

    rng = np.random.default_rng(16)
    z = rng.uniform(0.4, 0.9, (60, 80)).astype(np.float32)
    z[rng.random(z.shape) < 0.1] = np.nan
    rx, ry = (np.arange(80) * 2 - 79.5) / 150.0, (np.arange(60) * 2 - 59.5) / 150.0
    n = np.array([0.01, -0.8, -0.6]) / np.linalg.norm([0.01, -0.8, -0.6])
    for off in (0.45, 0.55, 0.6):
        want = np.zeros(z.shape, bool)
        want[::7] = True  # pixels already marked stay marked
        with np.errstate(invalid="ignore"):
            want |= np.abs(z * (n[0] * rx[None, :] + n[1] * ry[:, None] + n[2]) + off) < 0.015
        got = np.zeros(z.shape, bool)
        got[::7] = True
        _near_plane(z[:, :], rx, ry, n, off, 0.015, got)
        np.testing.assert_array_equal(got, want)
        assert 0 < (want & ~np.isnan(z)).sum() < z.size


def test_a_part_is_seen_only_inside_its_window():
    """The contact test renders a part's depth only inside its window (:meth:`HandLoop._part_window`): the slab test
    over a whole hands window finds no ray outside it, for parts turned every way, near and far, partly off the
    image."""
    from tracker.geometry.camera import Intrinsics
    from tracker.geometry.parts import PartSpec
    from tracker.geometry.pose import Pose
    from tracker.hands.loop import HandLoop, box_part_depth

    intr = Intrinsics(fx=600.0, fy=600.0, cx=319.5, cy=239.5, width=640, height=480)
    part = PartSpec.cube("red", "red")
    loop = HandLoop([part], intr)
    rng = np.random.default_rng(17)
    us, vs = np.arange(0, 640), np.arange(0, 480)
    seen = 0
    for _ in range(25):
        t = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.25, 0.25), rng.uniform(0.15, 0.9)])
        pose = Pose.from_rotvec(rng.normal(0, 1.5, 3), t)
        win = loop._part_window(part, pose, 480, 640)
        zr = box_part_depth(part, pose, intr, us, vs)
        if win is None:
            assert not np.isfinite(zr).any()
            continue
        u0, v0, u1, v1 = win
        inside = np.zeros(zr.shape, bool)
        inside[v0:v1, u0:u1] = True
        assert not np.isfinite(zr[~inside]).any()
        seen += bool(np.isfinite(zr).any())
    assert seen >= 10


def test_order_statistics_equal_numpy_quantile_and_median():
    """The palm anchors' quantile and median (one partition) return numpy's values bit for bit: ties, float32 depth,
    distances from a non-integer entry point, every size from 1 and the quantiles the anchors use."""
    from tracker.hands import order_stats

    rng = np.random.default_rng(21)
    for k in range(3000):
        n = int(rng.integers(1, 300))
        kind = k % 4
        if kind == 0:
            x = rng.normal(size=n)
        elif kind == 1:
            x = rng.integers(0, 4, n).astype(np.float64)  # many ties
        elif kind == 2:
            x = rng.uniform(0.3, 1.5, n).astype(np.float32)  # depth in metres
        else:
            e = rng.uniform(0.0, 40.0, 2)
            x = np.hypot(rng.integers(0, 40, n) - e[0], rng.integers(0, 40, n) - e[1])
        assert order_stats.median(x) == float(np.median(x))
        if x.dtype == np.float64:
            for q in (0.0, 0.37, 0.5, 0.75, 0.9, 1.0):
                thr = order_stats.quantile(x, q)
                assert thr == float(np.quantile(x, q))
                np.testing.assert_array_equal(x >= thr, x >= np.quantile(x, q))


def _exclusion_per_part(loop, depth, table_plane, poses):
    """The exclusion mask as :meth:`HandLoop.exclusion` made it before its parts went through one kernel call each
    (session 31): the strided working depth, the table plane, then per part its window, its rays and the marking."""
    from tracker.hands.loop import _box_rays, _mark_part_surface, _near_plane

    s = loop.tracker.s
    H, W = depth.shape
    z = depth[::s, ::s][: H // s, : W // s]
    out = np.zeros(z.shape, bool)
    intr = loop.intrinsics
    with np.errstate(invalid="ignore"):
        if table_plane is not None:
            n, off = table_plane
            rx = (np.arange(z.shape[1]) * s - intr.cx) / intr.fx
            ry = (np.arange(z.shape[0]) * s - intr.cy) / intr.fy
            _near_plane(z, rx, ry, np.asarray(n, np.float64), float(off), loop.config.table_clearance_m, out)
        for name, part in loop.parts.items():
            pose = poses.get(name)
            win = loop._part_window(part, pose, H, W)
            if win is None:
                continue
            u0, v0, u1, v1 = (-(-c // s) for c in win)
            u1, v1 = min(u1, z.shape[1]), min(v1, z.shape[0])  # (the old form went past a partial last column)
            if u1 <= u0 or v1 <= v0:
                continue
            half, R, o, x, y = _box_rays(part, pose, intr, np.arange(u0, u1) * s, np.arange(v0, v1) * s)
            _mark_part_surface(R, o, half, x, y, z, u0, v0, np.float32(loop.config.part_clearance_m), out)
    return out


def test_exclusion_equals_the_per_part_form():
    """:meth:`HandLoop.exclusion` (each part's window, rays and marking in one kernel call, on a contiguous working
    depth) marks exactly the pixels of the per-part numpy form: parts turned every way, near and far, partly off the
    image or behind the camera, a missing pose, NaN depth, float32 and float64 depth, working scales 2 and 3 (3 does
    not divide 640: windows end at the working image's last column)."""
    from tracker.geometry.camera import Intrinsics
    from tracker.geometry.parts import PartSpec
    from tracker.geometry.pose import Pose
    from tracker.hands.loop import HandLoop, HandLoopConfig, box_part_depth
    from tracker.hands.tracker import HandTrackerConfig

    intr = Intrinsics(fx=600.0, fy=605.0, cx=319.5, cy=241.0, width=640, height=480)
    parts = [PartSpec.cube("red", "red"), PartSpec.cube("blue", "blue"), PartSpec.cube("green", "green")]
    rng = np.random.default_rng(22)
    us, vs = np.arange(640), np.arange(480)
    marked = 0
    for trial in range(24):
        scale = 2 if trial % 3 else 3
        loop = HandLoop(parts, intr, HandLoopConfig(tracker=HandTrackerConfig(scale=scale)))
        poses = {}
        for p in parts:
            t = np.array([rng.uniform(-0.35, 0.35), rng.uniform(-0.3, 0.3), rng.uniform(-0.05, 0.9)])
            poses[p.name] = Pose.from_rotvec(rng.normal(0, 1.5, 3), t)
        if trial % 4 == 0:
            poses.pop("blue")
        depth = np.full((480, 640), 0.8, np.float64 if trial % 5 == 0 else np.float32)
        for name, pose in poses.items():  # measured depth near each part's surface: some pixels in front, some not
            zr = box_part_depth(loop.parts[name], pose, intr, us, vs)
            hit = np.isfinite(zr)
            depth[hit] = zr[hit] + rng.choice([-0.02, -0.0100001, -0.01, 0.0, 0.01], int(hit.sum()))
        depth[rng.random(depth.shape) < 0.03] = np.nan
        n = np.array([0.02, -0.8, -0.6]) / np.linalg.norm([0.02, -0.8, -0.6])
        plane = None if trial % 6 == 1 else (n, float(rng.uniform(0.4, 0.7)))
        want = _exclusion_per_part(loop, depth, plane, poses)
        got = loop.exclusion(depth, plane, poses)
        np.testing.assert_array_equal(got, want)
        marked += int(want.sum())
    assert marked > 1000


def _tube_cut_reference(xs, ys, e, d, reach, tip, behind):
    """:func:`tracker.hands.palm_cut.tube_cut` as numpy calls on the pixel lists (before session 31's kernels)."""
    from tracker.hands import order_stats
    from tracker.hands.palm_cut import TUBE_MIN_PX

    far = d >= order_stats.quantile(d, 0.9)
    a = np.array([xs[far].mean() - e[0], ys[far].mean() - e[1]])
    norm = float(np.hypot(a[0], a[1]))
    if norm < 1e-9:
        return None
    a /= norm
    p = (xs - e[0]) * a[0] + (ys - e[1]) * a[1]
    q = (ys - e[1]) * a[0] - (xs - e[0]) * a[1]
    pmax = float(p.max())
    start = pmax - reach
    piece = (p < start) & (p >= start - behind)
    if np.count_nonzero(piece) < TUBE_MIN_PX:
        piece = p < start
        if np.count_nonzero(piece) < TUBE_MIN_PX:
            return None
    pb = np.floor(p[piece]).astype(np.int64)
    lo = int(pb.min())
    pb -= lo
    n = int(pb.max()) + 1
    qp = q[piece]
    cnt = np.bincount(pb, minlength=n)
    qmin, qmax = np.full(n, np.inf), np.full(n, -np.inf)
    np.minimum.at(qmin, pb, qp)
    np.maximum.at(qmax, pb, qp)
    ok = cnt >= 2
    if np.count_nonzero(ok) < 3:
        return None
    pc = lo + np.flatnonzero(ok) + 0.5
    mid = 0.5 * (qmin[ok] + qmax[ok])
    pm, qm = pc.mean(), mid.mean()
    var = float(((pc - pm) ** 2).sum())
    slope = float(((pc - pm) * (mid - qm)).sum()) / var if var > 0 else 0.0
    icpt = qm - slope * pm
    r = order_stats.median(0.5 * (qmax[ok] - qmin[ok] + 1.0))
    dist = np.abs(q - (slope * p + icpt)) / np.sqrt(1.0 + slope * slope)
    sel = (p >= start) & ((dist > r) | (p >= pmax - tip))
    return sel if sel.any() else None


def _palm_cut_reference(comp, depth, scale, focal, hand_length_m, far_frac=0.25, origin=(0, 0), image_size=None,
                        tube=None):  # fmt: skip
    """:func:`tracker.hands.palm_cut.palm_cut` as numpy calls on the pixel lists (before session 31's kernels):
    (box, extent, l_hand, border, px_per_m)."""
    from tracker.hands import order_stats
    from tracker.hands.palm_cut import MIN_ARM_M, TUBE_BEHIND_M

    h, w = comp.shape
    if image_size is not None:
        w, h = image_size
    ys, xs = np.nonzero(comp)
    if origin != (0, 0):
        xs, ys = xs + origin[0], ys + origin[1]
    b = max(1, int(round(2.0 / scale)))
    edge = (xs < b) | (ys < b) | (xs >= w - b) | (ys >= h - b)
    border = bool(edge.any())
    e = np.array([xs[edge].mean(), ys[edge].mean()]) if border else np.array([xs.mean(), ys.mean()])
    d = np.hypot(xs - e[0], ys - e[1])
    z = 0.75
    if depth is not None:
        far = d >= order_stats.quantile(d, 1.0 - far_frac)
        dz = depth[np.minimum(ys[far] * scale, depth.shape[0] - 1), np.minimum(xs[far] * scale, depth.shape[1] - 1)]
        dz = dz[np.isfinite(dz) & (dz > 0)]
        if len(dz):
            z = order_stats.median(dz)
    l_hand = focal / scale * hand_length_m / z
    dmax = float(d.max())
    ppm = focal / scale / z
    sel = None
    if tube is not None and dmax > MIN_ARM_M * ppm:
        sel = _tube_cut_reference(xs, ys, e, d, tube[0] * ppm, tube[1] * ppm, TUBE_BEHIND_M * ppm)
    if sel is None:
        sel = d >= dmax - l_hand if dmax > l_hand else np.ones(len(d), bool)
    box = (int(xs[sel].min()), int(ys[sel].min()), int(xs[sel].max()), int(ys[sel].max()))
    return box, dmax, float(l_hand), border, ppm


def test_palm_cut_equals_the_numpy_form():
    """:func:`palm_cut` (its per-pixel passes compiled) gives the numpy form's box, extent, L_hand, border flag and
    px/m exactly: arms of random width and direction entering from each image side (tube cut), blobs inside the image
    (no border), crops with an origin, with and without depth (NaN holes, float32 and float64), scales 2 and 3."""
    import cv2

    from tracker.hands.palm_cut import palm_cut

    rng = np.random.default_rng(23)
    tubes = 0
    for trial in range(160):
        scale = 2 if trial % 4 else 3
        h, w = 480 // scale, 640 // scale
        mask = np.zeros((h, w), np.uint8)
        side = trial % 5
        end = (int(rng.integers(w // 4, 3 * w // 4)), int(rng.integers(h // 4, 3 * h // 4)))
        start = [(0, int(rng.integers(0, h))), (w - 1, int(rng.integers(0, h))), (int(rng.integers(0, w)), 0),
                 (int(rng.integers(0, w)), h - 1), end][side]  # fmt: skip
        cv2.line(mask, start, end, 1, int(rng.integers(6, 22)))  # the forearm (none for side 4)
        cv2.circle(mask, end, int(rng.integers(8, 20)), 1, -1)  # the hand
        mask[rng.random(mask.shape) < 0.02] = 0  # holes
        depth = None
        if trial % 3:
            depth = rng.uniform(0.35, 0.95, (480, 640)).astype(np.float64 if trial % 7 == 0 else np.float32)
            depth[rng.random(depth.shape) < 0.1] = np.nan
            depth[rng.random(depth.shape) < 0.02] = 0.0
        tube = None if trial % 6 == 5 else (float(rng.uniform(0.05, 0.12)), float(rng.uniform(0.01, 0.04)))
        x, y, bw, bh = cv2.boundingRect(mask)
        if trial % 2:  # a crop of the component with its origin, as palm_anchors passes it
            comp, origin, size = mask[y : y + bh, x : x + bw].astype(bool), (x, y), (w, h)
        else:
            comp, origin, size = mask, (0, 0), None
        focal = float(rng.uniform(450.0, 650.0))
        got = palm_cut(comp, depth, scale, focal, 0.19, origin=origin, image_size=size, tube=tube)
        want = _palm_cut_reference(comp, depth, scale, focal, 0.19, origin=origin, image_size=size, tube=tube)
        assert (got.box, got.extent, got.l_hand, got.border, got.px_per_m) == want, trial
        tubes += tube is not None and got.has_forearm
    assert tubes > 40
