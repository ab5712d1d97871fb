"""The simulator's sensor kernels, rewritten so that their loops vectorise, give the values of the one-loop kernels
they replaced (kept here as references, compiled with the same fast-math flags) on rendered frames and on random
inputs that reach every branch (clipping, missing depth, edges, grazing angles, both quantisations)."""

from __future__ import annotations

import numba as nb
import numpy as np
import pytest

from tracker.sources.simulator import SimulatedTable
from tracker.sources.simulator import sensor_model as sm
from tracker.sources.simulator.sensor_model import _FM, _MASK8, _S48, _gauss12, _hash, _u16


@nb.njit(cache=True, fastmath=_FM)
def _color_reference(color, out, key, gain, ramp_u, ramp_v, vignetting, sigma):
    h, w, _ = color.shape
    scale = sigma / 104.51314746403095
    for v in range(h):
        dv = v / h - 0.5
        gv = gain + ramp_v * dv
        for u in range(w):
            du = u / w - 0.5
            g = (gv + ramp_u * du) * (1.0 - vignetting * 2.0 * (du * du + dv * dv))
            hh = _hash(key, v * w + u, 2)
            for c in range(3):
                b1 = np.float64((hh >> np.uint64(16 * c)) & _MASK8)
                b2 = np.float64((hh >> np.uint64(16 * c + 8)) & _MASK8)
                val = color[v, u, c] * g + (b1 + b2 - 255.0) * scale + 0.5
                if val < 0.0:
                    val = 0.0
                elif val > 255.0:
                    val = 255.0
                out[v, u, c] = np.uint8(val)


@nb.njit(cache=True, fastmath=_FM)
def _depth_reference(clean, cosang, out, key, coeff, on_disp, quant, qstep, fb, dstep, jump, p_miss, p_fly, cos_start,
                     cos_end, p_drop, zmin, zmax, su, sv, shadow):  # fmt: skip
    h, w = clean.shape
    nan = np.float32(np.nan)
    for v in range(h):
        vs = v + sv
        for u in range(w):
            us = u + su
            if vs < 0 or vs >= h or us < 0 or us >= w:
                out[v, u] = nan
                continue
            z = clean[vs, us]
            if not (z >= zmin and z <= zmax) or shadow[vs, us]:
                out[v, u] = nan
                continue
            i = v * w + u
            h1 = _hash(key, i, 0)
            r_drop = np.float64(h1 >> _S48) * (1.0 / 65536.0)
            if r_drop < p_drop:
                out[v, u] = nan
                continue
            c = cosang[vs, us]
            if c < cos_start:
                p = (cos_start - c) / (cos_start - cos_end)
                if _u16(_hash(key, i, 2), 0) < p:
                    out[v, u] = nan
                    continue
            znear = z
            zfar = z
            if vs > 0:
                zn = clean[vs - 1, us]
                znear = min(znear, zn)
                zfar = max(zfar, zn if zn < zmax else zmax * 2.0)
            if vs < h - 1:
                zn = clean[vs + 1, us]
                znear = min(znear, zn)
                zfar = max(zfar, zn if zn < zmax else zmax * 2.0)
            if us > 0:
                zn = clean[vs, us - 1]
                znear = min(znear, zn)
                zfar = max(zfar, zn if zn < zmax else zmax * 2.0)
            if us < w - 1:
                zn = clean[vs, us + 1]
                znear = min(znear, zn)
                zfar = max(zfar, zn if zn < zmax else zmax * 2.0)
            thr = jump * z
            edge_fg = zfar - z > thr
            edge_bg = z - znear > thr
            if edge_fg or edge_bg:
                h3 = _hash(key, i, 3)
                r_edge = _u16(h3, 0)
                if r_edge < p_miss:
                    out[v, u] = nan
                    continue
                if r_edge < p_miss + p_fly:
                    other = zfar if edge_fg else znear
                    if other > zmax:
                        out[v, u] = nan
                        continue
                    z = z + (other - z) * _u16(h3, 1)
            n = _gauss12(h1)
            sigma = coeff * z * z
            if on_disp:
                d = fb / z
                d = d + n * sigma * fb / (z * z)
                if quant == 2:
                    d = np.floor(d / dstep + 0.5) * dstep
                if d <= 0.0:
                    out[v, u] = nan
                    continue
                z = fb / d
            else:
                z = z + n * sigma
                if quant == 2:
                    d = np.floor(fb / z / dstep + 0.5) * dstep
                    z = fb / d
            if quant == 1:
                z = np.floor(z / qstep + 0.5) * qstep
            if z < zmin or z > zmax:
                out[v, u] = nan
            else:
                out[v, u] = np.float32(z)


def _inputs() -> list[tuple[np.ndarray, np.ndarray, np.ndarray, int]]:
    """(clean depth, cosang, clean colour, frame key): two rendered frames (one with the hand) and random arrays."""
    src = SimulatedTable("guidance-demo", seed=0)
    out = []
    for k in (0, 130):
        c = src.render_clean(k)
        out.append((c["depth"].copy(), c["cosang"].copy(), c["color"].copy(), src.frame_key(k)))
    rng = np.random.default_rng(5)
    z = rng.uniform(0.2, 4.5, (120, 160)).astype(np.float32)
    z[rng.random(z.shape) < 0.05] = np.inf
    out.append((z, rng.uniform(0, 1, z.shape).astype(np.float32),
                (rng.random((120, 160, 3)) * 320 - 30).astype(np.float32), 987654321))  # fmt: skip
    return out


INPUTS = _inputs()


@pytest.mark.parametrize("noise_sigma, vignetting", [(2.5, 0.15), (9.0, 0.4)])
def test_colour_kernel_equals_the_one_loop_reference(noise_sigma, vignetting):
    clipped = 0
    for _, _, color, key in INPUTS:
        for gain, ru, rv in ((1.0, 0.0, 0.0), (1.07, 0.05, -0.08)):
            a, b = np.empty(color.shape, np.uint8), np.empty(color.shape, np.uint8)
            sm._color_kernel(color, a, np.uint64(key), gain, ru, rv, vignetting, noise_sigma)
            _color_reference(color, b, np.uint64(key), gain, ru, rv, vignetting, noise_sigma)
            assert np.array_equal(a, b)
            clipped += int(np.count_nonzero((a == 0) | (a == 255)))
    assert clipped > 100  # the clipping was reached


def test_colour_kernel_on_tiny_images_and_rounding_boundaries_equals_the_one_loop_reference():
    """Images 1–5 pixels wide and high (the flat row slices), colours on multiples of 1/8 (values at the rounding
    and clipping boundaries) and random gains: every value is the reference's."""
    rng = np.random.default_rng(12)
    for h in range(1, 6):
        for w in range(1, 6):
            color = (np.round(rng.uniform(-40, 300, (h, w, 3)) * 8) / 8).astype(np.float32)
            args = (np.uint64(100 * h + w), rng.uniform(0.9, 1.1), rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1),
                    0.15, 2.5)  # fmt: skip
            a, b = np.full(color.shape, 7, np.uint8), np.full(color.shape, 7, np.uint8)
            sm._color_kernel(color, a, *args)
            _color_reference(color, b, *args)
            assert np.array_equal(a, b)
    color = (np.round(rng.uniform(-40, 300, (96, 128, 3)) * 8) / 8).astype(np.float32)
    for key in range(6):
        args = (np.uint64(key), rng.uniform(0.9, 1.1), rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), 0.15, 2.5)
        a, b = np.empty(color.shape, np.uint8), np.empty(color.shape, np.uint8)
        sm._color_kernel(color, a, *args)
        _color_reference(color, b, *args)
        assert np.array_equal(a, b)


def test_colour_model_writes_into_an_output_of_any_strides():
    """``ColorSensorModel.apply`` into a non-contiguous ``out`` (the kernel takes C-contiguous buffers) gives the
    values of a fresh output, written into that array."""
    rng = np.random.default_rng(13)
    model = sm.ColorSensorModel()
    color = (rng.random((30, 40, 3)) * 255).astype(np.float32)
    fresh = model.apply(color, 5, 0.2, 0.3)
    big = np.zeros((30, 80, 3), np.uint8)
    out = big[:, ::2]
    assert model.apply(color, 5, 0.2, 0.3, out=out) is out
    assert np.array_equal(out, fresh) and not big[:, 1::2].any()


@pytest.mark.parametrize("model", [
    sm.DepthSensorModel(),
    sm.DepthSensorModel(noise_on="disparity", quantization="disparity"),
    sm.DepthSensorModel(quantization="none", shift_u=-1, shift_v=1, projector_baseline=-0.05),
    sm.DepthSensorModel(shift_u=-1, shift_v=1),  # the branch-free loop (noise on depth, mm) with other shifts
    sm.DepthSensorModel(shift_u=0, shift_v=-1, edge_missing=0.2, edge_flying=0.5, dropout=0.05),
])  # fmt: skip
def test_depth_kernel_equals_the_one_loop_reference(model):
    for clean, cosang, _, key in INPUTS:
        shadow = np.zeros(clean.shape, np.bool_)
        sm._projector_shadow(clean, 525.0 * abs(model.projector_baseline), model.projector_baseline > 0, shadow)
        args = (np.uint64(key), model.noise_coeff, model.noise_on == "disparity",
                {"none": 0, "mm": 1, "disparity": 2}[model.quantization], model.quant_step, model.focal_baseline,
                model.disparity_step, model.edge_jump, model.edge_missing, model.edge_flying,
                float(np.cos(np.radians(model.grazing_start_deg))), float(np.cos(np.radians(model.grazing_end_deg))),
                model.dropout, model.min_range, model.max_range, model.shift_u, model.shift_v, shadow)  # fmt: skip
        a, b = np.empty(clean.shape, np.float32), np.empty(clean.shape, np.float32)
        sm._depth_kernel(clean, cosang, a, *args)
        _depth_reference(clean, cosang, b, *args)
        assert np.array_equal(a, b, equal_nan=True)
        assert np.isnan(a).any() and np.isfinite(a).any()


@nb.njit(cache=True, fastmath=_FM)
def _projector_shadow_reference(clean, fxb, right, shadow):
    """The projector shadow as compiled before numpy's error model (each division checked its divisor: scalar)."""
    h, w = clean.shape
    c = np.empty(w)
    for v in range(h):
        if right:
            for u in range(w):
                c[u] = u - fxb / clean[v, u]
            m = 1e30
            for u in range(w - 1, -1, -1):
                shadow[v, u] = m < c[u] - 0.5
                m = min(m, c[u])
        else:
            for u in range(w):
                c[u] = u + fxb / clean[v, u]
            m = -1e30
            for u in range(w):
                shadow[v, u] = m > c[u] + 0.5
                m = max(m, c[u])


@pytest.mark.parametrize("right", [True, False])
def test_projector_shadow_equals_the_checked_division_reference_and_its_definition(right):
    """The vectorised rows (numpy's error model) give the masks of the former scalar kernel on rendered frames and on
    random depths with gaps (inf); on small random rows every pixel is shadowed exactly when a pixel on the projector's
    side has a projector column more than half a pixel nearer (the definition, in numpy)."""
    rng = np.random.default_rng(14)
    depths = [clean for clean, _, _, _ in INPUTS]
    for shape in ((61, 97), (62, 40), (3, 5), (1, 1), (7, 2)):  # row counts not multiples of four (the rows' groups)
        z = rng.uniform(0.3, 4.0, shape).astype(np.float32)
        z[rng.random(z.shape) < 0.1] = np.inf
        depths.append(z)
    fxb = 525.0 * 0.075
    mixed = 0
    for clean in depths:
        a, b = np.zeros(clean.shape, np.bool_), np.ones(clean.shape, np.bool_)
        sm._projector_shadow(clean, fxb, right, a)
        _projector_shadow_reference(clean, fxb, right, b)
        assert np.array_equal(a, b)
        rows = np.ones(clean.shape[0], np.bool_)
        c = np.zeros(clean.shape, np.bool_)
        sm._projector_shadow_rows(clean, fxb, right, c, rows, ~rows, c)
        assert np.array_equal(a, c)
        some = rng.random(clean.shape[0]) < 0.6  # any rows, in groups of four and a rest
        base = rng.random(clean.shape) < 0.5
        d = np.full(clean.shape, True)
        sm._projector_shadow_rows(clean, fxb, right, d, some, ~some, base)
        assert np.array_equal(d[some], a[some]) and np.array_equal(d[~some], base[~some])
        mixed += int(a.any() and not a.all())
    assert mixed >= 3  # shadowed and lit pixels in the rendered frames and the larger random depths
    z = depths[len(INPUTS)][:5]
    shadow = np.zeros(z.shape, np.bool_)
    sm._projector_shadow(z, fxb, right, shadow)
    cols = np.arange(z.shape[1]) + (-1.0 if right else 1.0) * fxb / z.astype(np.float64)
    for v in range(z.shape[0]):
        for u in range(z.shape[1]):
            if right:
                expect = u + 1 < z.shape[1] and cols[v, u + 1 :].min() < cols[v, u] - 0.5
            else:
                expect = u > 0 and cols[v, :u].max() > cols[v, u] + 0.5
            assert shadow[v, u] == expect


def test_projector_shadow_of_some_rows_computes_those_restores_the_marked_and_keeps_the_rest():
    model = sm.DepthSensorModel()
    clean, _, _, _ = INPUTS[1]  # a frame with the hand
    full = model.projector_shadow(clean)
    base = np.zeros_like(full)
    base[::7] = True
    out = np.ones_like(full)  # stands for the last frame's mask
    h = clean.shape[0]
    compute, restore = np.zeros(h, np.bool_), np.zeros(h, np.bool_)
    compute[100:300] = True
    restore[250:400] = True
    model.projector_shadow(clean, out=out, rows=(compute, restore, base))
    assert np.array_equal(out[100:300], full[100:300])
    assert np.array_equal(out[300:400], base[300:400])
    assert out[:100].all() and out[400:].all()
    assert full[100:300].any() and not full[100:300].all()  # the computed rows have shadow and lit pixels


@pytest.mark.parametrize("shift_u, shift_v", [(1, 0), (-1, 1), (0, -1)])
def test_depth_kernel_on_tiny_images_equals_the_one_loop_reference(shift_u, shift_v):
    """Images 1–5 pixels wide and high: the branch-free loop's row slices (empty or one pixel long) stay inside the
    image and every pixel gets the reference's value."""
    model = sm.DepthSensorModel(shift_u=shift_u, shift_v=shift_v, dropout=0.05)
    rng = np.random.default_rng(11)
    for h in range(1, 6):
        for w in range(1, 6):
            clean = rng.uniform(0.5, 1.5, (h, w)).astype(np.float32)
            clean[rng.random(clean.shape) < 0.1] = np.inf
            cosang = rng.uniform(0, 1, clean.shape).astype(np.float32)
            shadow = rng.random(clean.shape) < 0.1
            args = (np.uint64(1000 * h + w), model.noise_coeff, False, 1, model.quant_step, model.focal_baseline,
                    model.disparity_step, model.edge_jump, model.edge_missing, model.edge_flying, 0.26, 0.05,
                    model.dropout, model.min_range, model.max_range, shift_u, shift_v, shadow)  # fmt: skip
            a, b = np.full(clean.shape, 7.0, np.float32), np.full(clean.shape, 7.0, np.float32)
            sm._depth_kernel(clean, cosang, a, *args)
            _depth_reference(clean, cosang, b, *args)
            assert np.array_equal(a, b, equal_nan=True) and not (a == 7.0).any()
