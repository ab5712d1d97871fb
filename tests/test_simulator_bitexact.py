"""Speed-ups of the simulator keep its frames bit-identical: the changed kernels against references (the previous
implementations' semantics, kept here), and consecutive frames of several scenarios (a moving camera, two hands)
against the same frames rendered afresh by a new table with no buffers reused."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.sources.simulator import SimulatedTable
from tracker.sources.simulator import rasterizer as rz
from tracker.sources.simulator.sensor_model import ColorSensorModel
from tracker.sources.simulator.source import SimOptions


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
