"""Projective point-to-plane refinement of a rigid hand-patch motion against a full-resolution depth image.

The hand carry (:mod:`tracker.filter.hand_carry`) registers last frame's hand patch to this frame's hand points by
nearest-neighbour point-to-plane ICP on points sampled every ``carry_stride`` pixels and thinned to a few hundred.
On a curved surface that pairing is biased: a patch point's nearest sample lies a few millimetres along the surface,
and on a convex surface (the simulated hand is capsules of 0.8-1 cm radius) the tangent plane there passes in front
of the point by about κ s² / 2, so every pair pulls the patch outward, which for the hand's visible side is toward
the camera (traced on a hidden carry, session 31: 0.29 mm a frame toward the camera on noise-free depth of a rigid
hand, 0.57 mm on the sensor model's depth; 0 with the hand still, where both frames sample the same pixels).

Here each moved patch point is paired with the pixel it projects to in the depth image (projective association,
as dense RGB-D odometry does): the paired surface point lies on the same viewing ray within half a pixel, so the
tangent-plane gap vanishes; the normal comes from the image neighbours ``STENCIL`` pixels away (pairs across a depth
jump there, at the hand's rim, are dropped). The refinement starts from the nearest-neighbour result, so the
projective pairing, which needs a close start, only finishes it.

Units: metres, radians; points, rotation vectors and translations in the camera frame; the motion is about the
patch centroid c: x' = R(w) (x − c) + c + t.
"""

from __future__ import annotations

import numpy as np

from tracker.filter.motion_model import rotvec_to_matrix
from tracker.geometry.camera import Intrinsics
from tracker.geometry.point_icp import matrix_rotvec

STENCIL = 2
"""Pixels from the paired pixel to the neighbours whose points give its normal (cross product of the horizontal and
vertical differences)."""

EDGE = 0.01
"""Largest depth difference (m) between the paired pixel and each stencil neighbour: a larger one is a depth jump
(the hand's rim, or another surface): the pair is dropped."""

GATE = 0.02
"""Largest point-to-plane residual (m) of a pair, and half the largest difference in depth between the moved point
and its pixel; pairs beyond either are dropped (a point the hand turned out of view, the table or a part behind)."""


def _pixel_points(depth: np.ndarray, u: np.ndarray, v: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """Camera-frame points (M, 3) of pixels (``u``, ``v``) of ``depth`` (m; NaN where none)."""
    z = depth[v, u].astype(np.float64)
    return np.stack([(u - intrinsics.cx) / intrinsics.fx * z, (v - intrinsics.cy) / intrinsics.fy * z, z], -1)


def refine_projective(src: np.ndarray, depth: np.ndarray, intrinsics: Intrinsics, w: np.ndarray, t: np.ndarray,
                      rounds: int, plane: tuple[np.ndarray, float] | None = None, min_height: float = 0.0,
                      exclude: list[tuple[np.ndarray, float]] = ()) -> tuple[np.ndarray, np.ndarray]:
    """Refine the rigid motion (``w`` rad, ``t`` m, about ``src``'s centroid) of point set ``src`` (M, 3) onto the
    surface seen in ``depth`` (H, W; m, NaN or 0 = none) by at most ``rounds`` Gauss-Newton rounds of projective
    point-to-plane pairing (damped as :func:`tracker.geometry.point_icp.rigid_icp` damps). Pixels whose points lie
    at most ``min_height`` above the table ``plane`` (n·x + offset; None = no test) or inside a sphere of
    ``exclude`` [(centre, radius)] are not the hand's and pair with nothing. Returns the refined (w, t), or the given
    ones when fewer than 6 pairs are found in the first round."""
    w = np.asarray(w, np.float64).copy()
    t = np.asarray(t, np.float64).copy()
    if src.shape[0] < 6 or rounds <= 0:
        return w, t
    h, wd = depth.shape
    k = STENCIL
    c = src.mean(axis=0)
    rel = src - c
    radius2 = max(float((rel**2).sum(1).mean()), 1e-6)
    ex_c = np.array([e for e, _ in exclude], np.float64).reshape(-1, 3)
    ex_r2 = np.array([r * r for _, r in exclude], np.float64)
    for _ in range(rounds):
        R = rotvec_to_matrix(w)[0]
        q = rel @ R.T
        m = q + c + t
        z = np.where(m[:, 2] > 0.05, m[:, 2], np.nan)
        with np.errstate(invalid="ignore"):
            uf = np.rint(m[:, 0] / z * intrinsics.fx + intrinsics.cx)
            vf = np.rint(m[:, 1] / z * intrinsics.fy + intrinsics.cy)
            ok = (uf >= k) & (uf < wd - k) & (vf >= k) & (vf < h - k)
        u = np.where(ok, uf, k).astype(np.int64)
        v = np.where(ok, vf, k).astype(np.int64)
        p = _pixel_points(depth, u, v, intrinsics)
        right, left = _pixel_points(depth, u + k, v, intrinsics), _pixel_points(depth, u - k, v, intrinsics)
        down, up = _pixel_points(depth, u, v + k, intrinsics), _pixel_points(depth, u, v - k, intrinsics)
        n = np.cross(right - left, down - up)
        norm = np.linalg.norm(n, axis=1)
        with np.errstate(invalid="ignore"):
            ok &= np.isfinite(norm) & (norm > 0) & (p[:, 2] > 0)
            for nb in (right, left, down, up):
                ok &= np.abs(nb[:, 2] - p[:, 2]) < EDGE
            if plane is not None:
                ok &= p @ np.asarray(plane[0], np.float64) + float(plane[1]) > min_height
            for e in range(ex_c.shape[0]):
                ok &= ((p - ex_c[e]) ** 2).sum(1) > ex_r2[e]
            n = n / np.where(norm > 0, norm, 1.0)[:, None]
            res = np.einsum("mi,mi->m", n, p - m)
            ok &= (np.abs(res) < GATE) & (np.abs(p[:, 2] - m[:, 2]) < 2 * GATE)
        if ok.sum() < 6:
            break
        n, res, qi = n[ok], res[ok], q[ok]
        jac = np.hstack([np.cross(qi, n), n])
        a = jac.T @ jac
        b = jac.T @ res
        tr = float(np.trace(a[3:, 3:]))
        a[:3, :3] += np.eye(3) * (1e-2 * tr / 3.0 * radius2)
        a[3:, 3:] += np.eye(3) * (1e-3 * tr)
        x = np.linalg.solve(a, b)
        R_new = rotvec_to_matrix(x[:3])[0] @ R
        w = matrix_rotvec(np.ascontiguousarray(R_new))
        t = t + x[3:]
        if np.linalg.norm(x[3:]) < 2e-5 and np.linalg.norm(x[:3]) < 5e-5:
            break
    return w, t

