"""Speed-ups of the simulator keep its frames bit-identical: the changed kernels against references (the previous
implementations' semantics, kept here), and consecutive frames of several scenarios (a moving camera, two hands)
against the same frames rendered afresh by a new table with no buffers reused."""

from __future__ import annotations

import numba as nb
import numpy as np
import pytest

from tracker.sources.simulator import SimulatedTable
from tracker.sources.simulator import rasterizer as rz
from tracker.sources.simulator.rasterizer import _FM, _shade
from tracker.sources.simulator.sensor_model import ColorSensorModel
from tracker.sources.simulator.source import SimOptions


@nb.njit(cache=True, fastmath=_FM)
def _capsule_reference(depth, cosang, color, ids, hits, fx, fy, cx, cy, pa, pb, radius, albedo, light, ambient, diffuse,
                       pid, u0, v0, u1, v1):  # fmt: skip
    """``render_capsule`` as it was before the table of ray directions: the rays computed per pixel."""
    ba0 = pb[0] - pa[0]
    ba1 = pb[1] - pa[1]
    ba2 = pb[2] - pa[2]
    # oa = ro - pa with ro = 0
    oa0 = -pa[0]
    oa1 = -pa[1]
    oa2 = -pa[2]
    baba = ba0 * ba0 + ba1 * ba1 + ba2 * ba2
    baoa = ba0 * oa0 + ba1 * oa1 + ba2 * oa2
    oaoa = oa0 * oa0 + oa1 * oa1 + oa2 * oa2
    r2 = radius * radius
    for v in range(v0, v1):
        yv = (v - cy) / fy
        for u in range(u0, u1):
            xu = (u - cx) / fx
            dn = np.sqrt(xu * xu + yv * yv + 1.0)
            r0 = xu / dn
            r1 = yv / dn
            rz = 1.0 / dn
            bard = ba0 * r0 + ba1 * r1 + ba2 * rz
            rdoa = r0 * oa0 + r1 * oa1 + rz * oa2
            a = baba - bard * bard
            b = baba * rdoa - baoa * bard
            c = baba * oaoa - baoa * baoa - r2 * baba
            h = b * b - a * c
            tt = -1.0
            if h >= 0.0 and a > 1e-18:
                tb = (-b - np.sqrt(h)) / a
                y = baoa + tb * bard
                if y > 0.0 and y < baba:
                    tt = tb
                else:
                    # spherical caps
                    if y <= 0.0:
                        c0, c1, c2 = oa0, oa1, oa2
                    else:
                        c0, c1, c2 = -pb[0], -pb[1], -pb[2]
                    bb = r0 * c0 + r1 * c1 + rz * c2
                    cc = c0 * c0 + c1 * c1 + c2 * c2 - r2
                    hh = bb * bb - cc
                    if hh > 0.0:
                        tt = -bb - np.sqrt(hh)
            if tt <= 0.0:
                continue
            hits[pid] += 1
            z = tt * rz
            if z >= depth[v, u]:
                continue
            px = tt * r0
            py = tt * r1
            pz = tt * rz
            s = ((px - pa[0]) * ba0 + (py - pa[1]) * ba1 + (pz - pa[2]) * ba2) / baba
            s = min(max(s, 0.0), 1.0)
            nx = (px - pa[0] - ba0 * s) / radius
            ny = (py - pa[1] - ba1 * s) / radius
            nz = (pz - pa[2] - ba2 * s) / radius
            depth[v, u] = z
            cosang[v, u] = abs(nx * r0 + ny * r1 + nz * rz)
            ids[v, u] = pid
            _shade(color, v, u, albedo, nx, ny, nz, light, ambient, diffuse, 1.0)


def test_capsules_with_the_ray_table_equal_the_per_pixel_rays():
    rng = np.random.default_rng(7)
    H, W = 120, 160
    fx, fy, cx, cy = 140.0, 140.0, (W - 1) / 2.0, (H - 1) / 2.0
    rays = rz.ray_directions(fx, fy, cx, cy, W, H)
    bufs = [np.full((H, W), np.inf, np.float32), np.ones((H, W), np.float32), np.zeros((H, W, 3), np.float32),
            np.full((H, W), -1, np.int16), np.zeros(8, np.int64)]  # fmt: skip
    ref = [b.copy() for b in bufs]
    light = np.array([0.3, -0.8, -0.5]) / np.linalg.norm([0.3, -0.8, -0.5])
    for k in range(60):  # overlapping capsules: the z-test between them is exercised too
        pa = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), rng.uniform(0.4, 1.2)])
        pb = pa + rng.normal(0.0, 0.08, 3)
        radius, albedo = rng.uniform(0.005, 0.04), rng.uniform(50, 250, 3)
        rect = rz.points_rect(
            np.concatenate([pa + radius * _cube_signs(), pb + radius * _cube_signs()]), fx, fy, cx, cy, W, H
        )
        if rect is None:
            continue
        rz.render_capsule(*bufs, rays, pa, pb, radius, albedo, light, 0.35, 0.65, k % 8, *rect)
        _capsule_reference(*ref, fx, fy, cx, cy, pa, pb, radius, albedo, light, 0.35, 0.65, k % 8, *rect)
    for a, b in zip(bufs, ref, strict=True):
        assert np.array_equal(a, b)
    assert np.count_nonzero(bufs[3] >= 0) > 2000  # the capsules covered many pixels


def _cube_signs() -> np.ndarray:
    """The 8 corners of the unit cube [-1, 1]^3."""
    return np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)


def _restore_reference(rects, color_rects, depth, cosang, color, ids, bg_depth, bg_cos, bg_color):
    """Per-pixel semantics of ``restore_rects``: colour from the background under any rectangle, the geometry
    buffers (and ids = -1) under the geometry rectangles alone (clipped to the image)."""
    H, W = depth.shape
    geo = np.zeros((H, W), bool)
    col = np.zeros((H, W), bool)
    for r, m in ((rects, geo), (color_rects, col)):
        for u0, v0, u1, v1 in r:
            m[max(v0, 0) : min(v1, H), max(u0, 0) : min(u1, W)] = True
    any_ = geo | col
    color[any_] = bg_color[any_]
    depth[geo], cosang[geo], ids[geo] = bg_depth[geo], bg_cos[geo], -1


def test_restore_rects_equals_the_per_pixel_reference():
    rng = np.random.default_rng(3)
    H, W = 60, 80
    bg = (rng.random((H, W)).astype(np.float32), rng.random((H, W)).astype(np.float32),
          rng.random((H, W, 3)).astype(np.float32))  # fmt: skip
    changed = 0
    for _ in range(40):

        def rects(n):
            r = np.empty((n, 4), np.int64)
            for i in range(n):
                u0, v0 = rng.integers(-10, W), rng.integers(-10, H)
                # ends >= 1 (callers clip their rectangles; one ending left of / above the image is not asked for)
                r[i] = (u0, v0, max(u0 + rng.integers(0, 40), 1), max(v0 + rng.integers(0, 30), 1))
            return r

        geo, col = rects(int(rng.integers(0, 6))), rects(int(rng.integers(0, 3)))
        bufs = (rng.random((H, W)).astype(np.float32), rng.random((H, W)).astype(np.float32),
                rng.random((H, W, 3)).astype(np.float32), rng.integers(0, 9, (H, W)).astype(np.int16))  # fmt: skip
        a = tuple(b.copy() for b in bufs)
        b = tuple(x.copy() for x in bufs)
        rz.restore_rects(geo, col, *a, *bg)
        _restore_reference(geo, col, *b, *bg)
        for x, y in zip(a, b, strict=True):
            assert np.array_equal(x, y)
        changed += int(np.count_nonzero(a[2] != bufs[2]))
    assert changed > 1000  # the rectangles did restore pixels


def test_colour_model_with_a_reused_scratch_buffer_equals_a_fresh_blur():
    rng = np.random.default_rng(4)
    model = ColorSensorModel()
    scratch = np.empty((48, 64, 3), np.float32)
    for key in range(3):
        color = (rng.random((48, 64, 3)) * 255).astype(np.float32)
        a = model.apply(color, key, 0.1 * key, 0.3, scratch=scratch)
        b = model.apply(color, key, 0.1 * key, 0.3)
        assert np.array_equal(a, b)
    wrong = np.empty((10, 10, 3), np.float32)  # a scratch of another shape is not used
    assert np.array_equal(model.apply(color, 9, 0.0, 0.3, scratch=wrong), model.apply(color, 9, 0.0, 0.3))


@pytest.mark.parametrize("name, seed, motion, start", [
    ("guidance-demo", 1, "none", 95),
    ("hands-s2", 1, "none", 60),
    ("static", 2, "sway", 10),
    ("free", 3, "sway", 120),
])  # fmt: skip
def test_consecutive_frames_equal_frames_rendered_afresh(name, seed, motion, start):
    opts = SimOptions(camera_motion=motion)
    seq = SimulatedTable(name, seed=seed, options=opts)
    seq.render(start - 1)
    for k in range(start, start + 5):
        a, b = seq.render(k), SimulatedTable(name, seed=seed, options=opts).render(k)
        assert np.array_equal(a.color, b.color)
        assert np.array_equal(a.depth, b.depth, equal_nan=True)
        ga, gb = a.meta["groundtruth"], b.meta["groundtruth"]
        assert ga.keys() == gb.keys()
        for key in ga:
            if key == "skin_mask":
                assert np.array_equal(ga[key], gb[key])
            elif key == "poses":
                for p in ga[key]:
                    assert np.array_equal(ga[key][p].R, gb[key][p].R) and np.array_equal(ga[key][p].t, gb[key][p].t)
            elif key == "camera_pose":
                assert np.array_equal(ga[key].R, gb[key].R) and np.array_equal(ga[key].t, gb[key].t)
            else:
                assert ga[key] == gb[key], key
