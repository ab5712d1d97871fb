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

A round is one compiled pass (:func:`_projective_kernel`, numba, as :func:`tracker.geometry.point_icp.rigid_icp`;
its 6×6 normal equations solved by Cholesky); :func:`refine_projective_numpy` is the same computation in numpy, kept
as the reference the kernel is tested against: the sums run in another order and the solve differs, so the two agree
to rounding (1e-15 on a traced session's carries), not to the bit.

Units: metres, radians; points, rotation vectors and translations in the camera frame; the motion is about the
patch centroid c: x' = R(w) (x − c) + c + t.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from tracker.filter.motion_model import rotvec_to_matrix
from tracker.geometry.camera import Intrinsics
from tracker.geometry.point_icp import matrix_rotvec, rotvec_matrix
from tracker.geometry.spd_solve import solve_spd6

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


def refine_projective_numpy(src: np.ndarray, depth: np.ndarray, intrinsics: Intrinsics, w: np.ndarray, t: np.ndarray,
                      rounds: int, plane: tuple[np.ndarray, float] | None = None, min_height: float = 0.0,
                      exclude: list[tuple[np.ndarray, float]] = ()) -> tuple[np.ndarray, np.ndarray]:
    """Refine the rigid motion (``w`` rad, ``t`` m, about ``src``'s centroid) of point set ``src`` (M, 3) onto the
    surface seen in ``depth`` (H, W; m, NaN or 0 = none) by at most ``rounds`` Gauss-Newton rounds of projective
    point-to-plane pairing (damped as :func:`tracker.geometry.point_icp.rigid_icp` damps). Pixels whose points lie
    at most ``min_height`` above the table ``plane`` (n·x + offset; None = no test) or inside a sphere of
    ``exclude`` [(centre, radius)] are not the hand's and pair with nothing. Returns the refined (w, t), or the given
    ones when fewer than 6 pairs are found in the first round. The numpy form of :func:`refine_projective`."""
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



def refine_projective(src: np.ndarray, depth: np.ndarray, intrinsics: Intrinsics, w: np.ndarray, t: np.ndarray,
                      rounds: int, plane: tuple[np.ndarray, float] | None = None, min_height: float = 0.0,
                      exclude: list[tuple[np.ndarray, float]] = ()) -> tuple[np.ndarray, np.ndarray]:
    """:func:`refine_projective_numpy` (see there for the arguments) as one compiled pass a round
    (:func:`_projective_kernel`): the same pairs and steps, equal to rounding."""
    w = np.asarray(w, np.float64).copy()
    t = np.asarray(t, np.float64).copy()
    if src.shape[0] < 6 or rounds <= 0:
        return w, t
    use_plane = plane is not None
    normal = np.asarray(plane[0], np.float64) if use_plane else np.zeros(3)
    offset = float(plane[1]) if use_plane else 0.0
    ex_c = np.array([e for e, _ in exclude], np.float64).reshape(-1, 3)
    ex_r2 = np.array([r * r for _, r in exclude], np.float64)
    return _projective_kernel(np.ascontiguousarray(src, np.float64), np.ascontiguousarray(depth), float(intrinsics.fx),
                              float(intrinsics.fy), float(intrinsics.cx), float(intrinsics.cy), w, t, int(rounds),
                              normal, offset, float(min_height), use_plane, ex_c, ex_r2)


@nb.njit(cache=True, inline="always")
def _pixel_point(depth, u, v, fx, fy, cx, cy):
    """Camera-frame point (x, y, z) of pixel (``u``, ``v``) of ``depth`` (z NaN where none)."""
    z = np.float64(depth[v, u])
    return (u - cx) / fx * z, (v - cy) / fy * z, z


@nb.njit(cache=True)
def _projective_kernel(src, depth, fx, fy, cx, cy, w0, t0, rounds, normal, offset, min_height, use_plane, ex_c, ex_r2):
    """:func:`refine_projective`'s rounds: ``src`` (M, 3) float64, ``depth`` (H, W) (m; NaN or 0 = none),
    pinhole ``fx, fy, cx, cy`` (px), start (``w0`` rad, ``t0`` m), table ``normal``·x + ``offset`` > ``min_height``
    (m) when ``use_plane``, exclusion spheres (``ex_c`` (E, 3) m, ``ex_r2`` (E,) m²). Returns (w, t)."""
    m = src.shape[0]
    h, wd = depth.shape
    k = STENCIL
    c = np.zeros(3)
    for i in range(m):
        for a in range(3):
            c[a] += src[i, a]
    for a in range(3):
        c[a] /= m
    rel = np.empty((m, 3))
    r2 = 0.0
    for i in range(m):
        for a in range(3):
            rel[i, a] = src[i, a] - c[a]
            r2 += rel[i, a] * rel[i, a]
    radius2 = max(r2 / m, 1e-6)
    w = w0.copy()
    t = t0.copy()
    for _ in range(rounds):
        R = rotvec_matrix(w)
        s00, s01, s02, s03, s04, s05, s11, s12, s13, s14, s15 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        s22, s23, s24, s25, s33, s34, s35, s44, s45, s55 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        g0, g1, g2, g3, g4, g5 = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        pairs = 0  # the normal equations' sums (upper triangle s, right side g) in scalars: kept in registers
        for i in range(m):
            r0, r1, r2_ = rel[i, 0], rel[i, 1], rel[i, 2]
            q0 = R[0, 0] * r0 + R[0, 1] * r1 + R[0, 2] * r2_
            q1 = R[1, 0] * r0 + R[1, 1] * r1 + R[1, 2] * r2_
            q2 = R[2, 0] * r0 + R[2, 1] * r1 + R[2, 2] * r2_
            m0, m1, m2 = q0 + c[0] + t[0], q1 + c[1] + t[1], q2 + c[2] + t[2]
            if not m2 > 0.05:
                continue
            uf = np.rint(m0 / m2 * fx + cx)
            vf = np.rint(m1 / m2 * fy + cy)
            if not (uf >= k and uf < wd - k and vf >= k and vf < h - k):
                continue
            u, v = int(uf), int(vf)
            p0, p1, p2 = _pixel_point(depth, u, v, fx, fy, cx, cy)
            if not p2 > 0.0:
                continue
            rx0, rx1, rx2 = _pixel_point(depth, u + k, v, fx, fy, cx, cy)
            lx0, lx1, lx2 = _pixel_point(depth, u - k, v, fx, fy, cx, cy)
            dy0, dy1, dy2 = _pixel_point(depth, u, v + k, fx, fy, cx, cy)
            uy0, uy1, uy2 = _pixel_point(depth, u, v - k, fx, fy, cx, cy)
            if not (abs(rx2 - p2) < EDGE and abs(lx2 - p2) < EDGE and abs(dy2 - p2) < EDGE and abs(uy2 - p2) < EDGE):
                continue
            if use_plane and not (p0 * normal[0] + p1 * normal[1] + p2 * normal[2] + offset > min_height):
                continue
            inside = False
            for e in range(ex_c.shape[0]):
                d0, d1, d2 = p0 - ex_c[e, 0], p1 - ex_c[e, 1], p2 - ex_c[e, 2]
                if not d0 * d0 + d1 * d1 + d2 * d2 > ex_r2[e]:
                    inside = True
                    break
            if inside:
                continue
            a0, a1, a2 = rx0 - lx0, rx1 - lx1, rx2 - lx2
            b0, b1, b2 = dy0 - uy0, dy1 - uy1, dy2 - uy2
            n0, n1, n2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
            norm = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
            if not (np.isfinite(norm) and norm > 0.0):
                continue
            n0, n1, n2 = n0 / norm, n1 / norm, n2 / norm
            res = n0 * (p0 - m0) + n1 * (p1 - m1) + n2 * (p2 - m2)
            if not (abs(res) < GATE and abs(p2 - m2) < 2 * GATE):
                continue
            pairs += 1
            j0, j1, j2 = q1 * n2 - q2 * n1, q2 * n0 - q0 * n2, q0 * n1 - q1 * n0
            j3, j4, j5 = n0, n1, n2
            g0, g1, g2 = g0 + j0 * res, g1 + j1 * res, g2 + j2 * res
            g3, g4, g5 = g3 + j3 * res, g4 + j4 * res, g5 + j5 * res
            s00, s01, s02 = s00 + j0 * j0, s01 + j0 * j1, s02 + j0 * j2
            s03, s04, s05 = s03 + j0 * j3, s04 + j0 * j4, s05 + j0 * j5
            s11, s12, s13, s14, s15 = s11 + j1 * j1, s12 + j1 * j2, s13 + j1 * j3, s14 + j1 * j4, s15 + j1 * j5
            s22, s23, s24, s25 = s22 + j2 * j2, s23 + j2 * j3, s24 + j2 * j4, s25 + j2 * j5
            s33, s34, s35 = s33 + j3 * j3, s34 + j3 * j4, s35 + j3 * j5
            s44, s45 = s44 + j4 * j4, s45 + j4 * j5
            s55 = s55 + j5 * j5
        if pairs < 6:
            break
        A = np.empty((6, 6))
        A[0, 0] = s00
        A[0, 1] = A[1, 0] = s01
        A[0, 2] = A[2, 0] = s02
        A[0, 3] = A[3, 0] = s03
        A[0, 4] = A[4, 0] = s04
        A[0, 5] = A[5, 0] = s05
        A[1, 1] = s11
        A[1, 2] = A[2, 1] = s12
        A[1, 3] = A[3, 1] = s13
        A[1, 4] = A[4, 1] = s14
        A[1, 5] = A[5, 1] = s15
        A[2, 2] = s22
        A[2, 3] = A[3, 2] = s23
        A[2, 4] = A[4, 2] = s24
        A[2, 5] = A[5, 2] = s25
        A[3, 3] = s33
        A[3, 4] = A[4, 3] = s34
        A[3, 5] = A[5, 3] = s35
        A[4, 4] = s44
        A[4, 5] = A[5, 4] = s45
        A[5, 5] = s55
        b = np.array([g0, g1, g2, g3, g4, g5])
        tr = A[3, 3] + A[4, 4] + A[5, 5]
        for a in range(3):
            A[a, a] += 1e-2 * tr / 3.0 * radius2
        for a in range(3, 6):
            A[a, a] += 1e-3 * tr
        x, ok = solve_spd6(A, b)
        if not ok:
            break
        w = matrix_rotvec(rotvec_matrix(x[:3]) @ R)
        for a in range(3):
            t[a] += x[3 + a]
        if np.sqrt(x[3] ** 2 + x[4] ** 2 + x[5] ** 2) < 2e-5 and np.sqrt(x[0] ** 2 + x[1] ** 2 + x[2] ** 2) < 5e-5:
            break
    return w, t


def warm_up() -> None:
    """Load (or compile) :func:`_projective_kernel` on tiny inputs of the types the hand carry passes it."""
    depth = np.full((16, 16), 0.5, np.float32)
    intr = Intrinsics(16, 16, 10.0, 10.0, 8.0, 8.0)
    g = np.linspace(-0.02, 0.02, 3)
    pts = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) + np.array([0.0, 0.0, 0.5])
    refine_projective(pts, depth, intr, np.zeros(3), np.zeros(3), 1, (np.array([0.0, 0.0, -1.0]), 0.6), 0.0,
                      [(np.array([0.0, 0.0, 0.4]), 0.01)])
