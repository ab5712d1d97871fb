"""``carry_projective`` (geometry/projective_icp.py): the projective refinement of the hand carry's registration."""

from __future__ import annotations

import numpy as np

from tracker.filter.hand_carry import _rot, above_table_points, register_rigid
from tracker.geometry.camera import Intrinsics
from tracker.geometry.projective_icp import refine_projective, refine_projective_numpy

INTR = Intrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)


def _fingers(shift: np.ndarray) -> np.ndarray:
    """Depth image (m, NaN = none) of four parallel cylinders (radius 9 mm, 10 cm long along the camera's x, 2 cm
    apart, at 0.45 m: a hand's fingers seen from above) moved by ``shift`` (m, camera frame)."""
    v, u = np.mgrid[0:480, 0:640].astype(np.float64)
    dx, dy = (u - INTR.cx) / INTR.fx, (v - INTR.cy) / INTR.fy
    depth = np.full((480, 640), np.nan)
    for k in range(4):
        c = np.array([0.0, -0.03 + 0.02 * k, 0.45]) + shift
        # the ray s (dx, dy, 1) meets the cylinder (y - c_y)² + (z - c_z)² = r² at its nearer root s
        a, b = dy**2 + 1.0, -2.0 * (dy * c[1] + c[2])
        disc = b * b - 4.0 * a * (c[1] ** 2 + c[2] ** 2 - 0.009**2)
        with np.errstate(invalid="ignore"):
            s = (-b - np.sqrt(np.where(disc > 0, disc, np.nan))) / (2.0 * a)
            s = np.where(np.abs(dx * s - c[0]) < 0.05, s, np.nan)
        depth = np.fmin(depth, s)
    return depth.astype(np.float32)


def _thinned(depth: np.ndarray, center: np.ndarray, radius: float) -> np.ndarray:
    """The hand points of ``depth`` within ``radius`` of ``center`` as the carry takes them: every second pixel,
    thinned evenly to at most 800."""
    pts = above_table_points(depth, INTR, center, radius, None, 0.0, 2, [])
    return pts[:: -(-pts.shape[0] // 800)]


def test_projective_pairing_removes_the_pull_toward_the_camera_of_a_convex_hand():
    """Noise-free fingers moved 0.7-8.4 mm across the viewing ray: the nearest-neighbour point-to-plane registration
    of the carry (thinned samples) pulls the patch toward the camera (each patch point's nearest sample lies along the
    convex surface, whose tangent plane there passes in front of it: 0.2 mm a frame); paired with the pixel each
    moved point projects to, the pull is gone and the motion across the ray is found."""
    part = np.array([0.0, 0.0, 0.47])  # behind the fingers, as a carried part is
    before = _fingers(np.zeros(3))
    src = _thinned(before, part, 0.08)
    nn, proj = [], []
    for k in range(1, 13):
        step = np.array([0.0, 0.0007 * k, 0.0])
        after = _fingers(step)
        w, t = register_rigid(src, _thinned(after, part + step, 0.13), 8, 0.05, 0.2)
        w2, t2 = refine_projective(src, after, INTR, w, t, 10)
        c = src.mean(axis=0)
        for out, (ww, tt) in ((nn, (w, t)), (proj, (w2, t2))):
            out.append(_rot(ww) @ (part - c) + c + tt - (part + step))
    nn, proj = np.array(nn), np.array(proj)
    assert nn[:, 2].mean() < -1e-4, nn[:, 2].mean()  # toward the camera (-0.20 mm)
    assert abs(proj[:, 2].mean()) < 2e-5, proj[:, 2].mean()  # (0.005 mm)
    assert np.abs(proj[:, 1]).max() < np.abs(nn[:, 1]).max()  # across the ray too


def test_projective_refinement_keeps_the_motion_without_enough_pairs():
    """An image without the patch's surface gives no pair: the given motion comes back unchanged."""
    src = _thinned(_fingers(np.zeros(3)), np.array([0.0, 0.0, 0.47]), 0.08)
    w, t = np.array([0.01, 0.0, 0.0]), np.array([0.0, 0.002, 0.0])
    w2, t2 = refine_projective(src, np.full((480, 640), np.nan, np.float32), INTR, w, t, 10)
    assert np.array_equal(w2, w) and np.array_equal(t2, t)


def test_the_compiled_refinement_is_the_numpy_form_to_rounding():
    """The compiled rounds (:func:`refine_projective`) against :func:`refine_projective_numpy` on the noisy fingers
    moved and turned, with a table plane that cuts the lowest finger off and an exclusion sphere over another: the
    same motion to rounding (1e-9 m, 1e-9 rad) over 12 steps, and the refinement moved it (it acted)."""
    rng = np.random.default_rng(3)
    part = np.array([0.0, 0.0, 0.47])
    src = _thinned(_fingers(np.zeros(3)), part, 0.08)
    plane = (np.array([0.0, 1.0, 0.0]), 0.025)  # height y + 0.025: the finger at y = -0.03 lies "below the table"
    exclude = [(np.array([0.0, 0.01, 0.45]), 0.012)]  # over the middle of the finger at y = 0.01
    moved = np.zeros(2, int)
    for k in range(1, 13):
        step = np.array([0.0004 * k, 0.0007 * k, -0.0003 * k])
        after = _fingers(step)
        after = after + rng.normal(0.0, 0.0005, after.shape).astype(np.float32)
        w, t = register_rigid(src, _thinned(after, part + step, 0.13), 8, 0.05, 0.2)
        for j, args in enumerate(((), (plane, 0.0, exclude))):
            a = refine_projective(src, after, INTR, w, t, 10, *args)
            b = refine_projective_numpy(src, after, INTR, w, t, 10, *args)
            assert np.allclose(a[0], b[0], rtol=0, atol=1e-9) and np.allclose(a[1], b[1], rtol=0, atol=1e-9), (a, b)
            moved[j] += np.linalg.norm(a[1] - t) > 1e-5
    assert moved.tolist() == [12, 12], moved
