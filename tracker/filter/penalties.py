"""Physical-plausibility penalties of the particle weights (spec sections 4.13–4.15).

* Intersection (4.48): c_i = λ_i when any two parts of a particle interpenetrate by more than the contact
  tolerance, 1 otherwise. Boxes use the exact separating-axis test for oriented boxes (15 axes); a mesh part
  is tested through its body-frame bounding box (conservative: may report contact a little early).
* Table sinking (4.49): c_h = exp(λ_h h_min) when the lowest vertex of all parts is below the table
  plane (h_min < 0, after an optional tolerance), 1 otherwise. Heights use the plane n·p + offset = 0 with the
  upward unit normal n in the camera frame.
Both are returned in log form, added to the particles' log-likelihood (4.50 corrected).
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def obb_overlap(Ra, ca, ha, Rb, cb, hb, tol):
    """True when two oriented boxes overlap by more than ``tol`` along every separating axis candidate.

    ``Ra``/``Rb`` body→camera rotations (columns = box axes), ``ca``/``cb`` centres, ``ha``/``hb`` half extents.
    """
    t0 = cb[0] - ca[0]
    t1 = cb[1] - ca[1]
    t2 = cb[2] - ca[2]
    for ax in range(15):
        if ax < 3:
            l0, l1, l2 = Ra[0, ax], Ra[1, ax], Ra[2, ax]
        elif ax < 6:
            l0, l1, l2 = Rb[0, ax - 3], Rb[1, ax - 3], Rb[2, ax - 3]
        else:
            i = (ax - 6) // 3
            j = (ax - 6) % 3
            a0, a1, a2 = Ra[0, i], Ra[1, i], Ra[2, i]
            b0, b1, b2 = Rb[0, j], Rb[1, j], Rb[2, j]
            l0 = a1 * b2 - a2 * b1
            l1 = a2 * b0 - a0 * b2
            l2 = a0 * b1 - a1 * b0
            n = np.sqrt(l0 * l0 + l1 * l1 + l2 * l2)
            if n < 1e-6:
                continue
            l0 /= n
            l1 /= n
            l2 /= n
        ra = 0.0
        rb = 0.0
        for m in range(3):
            ra += ha[m] * abs(Ra[0, m] * l0 + Ra[1, m] * l1 + Ra[2, m] * l2)
            rb += hb[m] * abs(Rb[0, m] * l0 + Rb[1, m] * l1 + Rb[2, m] * l2)
        sep = abs(t0 * l0 + t1 * l1 + t2 * l2) - (ra + rb)
        if sep > -tol:
            return False
    return True


@nb.njit(cache=True, inline="always")
def bounding_radii(half):
    """Radius (metres) of each part's bounding sphere about its box centre, from ``half`` (K, 3) half extents: (K,)."""
    k = half.shape[0]
    rad = np.empty(k)
    for o in range(k):
        rad[o] = np.sqrt(half[o, 0] ** 2 + half[o, 1] ** 2 + half[o, 2] ** 2)
    return rad


@nb.njit(cache=True, inline="always")
def world_centres(R, t, j, center, cw):
    """Particle ``j``'s box centres in the camera frame into ``cw`` (K, 3), from body-frame ``center`` (K, 3)."""
    for o in range(cw.shape[0]):
        for r in range(3):
            cw[o, r] = (R[j, o, r, 0] * center[o, 0] + R[j, o, r, 1] * center[o, 1] + R[j, o, r, 2] * center[o, 2]
                        + t[j, o, r])


@nb.njit(cache=True, inline="always")
def spheres_apart(cw, rad, a, b):
    """Are the bounding spheres of parts ``a`` and ``b`` apart (centres ``cw`` (K, 3), radii ``rad`` (K,))? Then the
    pair cannot interpenetrate; else the separating-axis test of the boxes (:func:`obb_overlap`) decides.

    (The two tests are written one after the other in the callers' loops, the box test called only for the pairs
    this one lets through: as one inlined function that returned early or called the box test, the pair test cost
    about 50 ns a pair, 5x the sphere test itself, on pairs whose spheres nearly always lie apart.)"""
    d2 = (cw[a, 0] - cw[b, 0]) ** 2 + (cw[a, 1] - cw[b, 1]) ** 2 + (cw[a, 2] - cw[b, 2]) ** 2
    return d2 > (rad[a] + rad[b]) ** 2


@nb.njit(cache=True)
def intersection_flags(R, t, center, half, pairs, tol):
    """Per particle: does any listed pair of parts interpenetrate by more than ``tol`` metres? (N,) bool.

    ``R`` (N, K, 3, 3), ``t`` (N, K, 3) poses; ``center``/``half`` (K, 3) body-frame box centre/half extents;
    ``pairs`` (M, 2) object index pairs worth testing.
    """
    n = R.shape[0]
    out = np.zeros(n, np.bool_)
    rad = bounding_radii(half)
    cw = np.empty((R.shape[1], 3))
    for j in range(n):
        world_centres(R, t, j, center, cw)
        for m in range(pairs.shape[0]):
            a, b = pairs[m, 0], pairs[m, 1]
            if not spheres_apart(cw, rad, a, b) and obb_overlap(R[j, a], cw[a], half[a], R[j, b], cw[b], half[b],
                                                                 tol):
                out[j] = True
                break
    return out


def boxes_intersect(pose_a, size_a, pose_b, size_b, tol: float = 0.0) -> bool:
    """Exact test for two boxes (Poses of their centres, full sizes): overlap deeper than ``tol`` metres."""
    R = np.stack([pose_a.R, pose_b.R])[None]
    t = np.stack([pose_a.t, pose_b.t])[None]
    half = np.asarray([size_a, size_b], np.float64) / 2.0
    return bool(intersection_flags(R, t, np.zeros((2, 3)), half, np.array([[0, 1]], np.int64), float(tol))[0])


def intersection_log_penalty(R, t, center, half, pairs, tol: float, lambda_i: float) -> np.ndarray:
    """log c_i per particle (N,): log λ_i where parts intersect, 0 elsewhere."""
    if len(pairs) == 0:
        return np.zeros(R.shape[0])
    flags = intersection_flags(R, t, center, half, pairs, float(tol))
    return np.where(flags, np.log(lambda_i), 0.0)


def lowest_heights(R: np.ndarray, t: np.ndarray, hulls: list[np.ndarray], normal: np.ndarray, offset: float):
    """Height above the table (metres) of the lowest vertex of all parts, per particle (N,).

    ``hulls[k]`` (V_k, 3) body-frame vertices of part k (8 corners for a box, convex-hull vertices for a mesh).
    """
    n = np.asarray(normal, np.float64)
    nb_ = np.einsum("nkij,i->nkj", R, n)  # Rᵀ n per particle and part
    base = t @ n + float(offset)  # (N, K)
    hmin = np.full(R.shape[0], np.inf)
    for k, verts in enumerate(hulls):
        h = nb_[:, k, :] @ np.asarray(verts, np.float64).T + base[:, k : k + 1]
        hmin = np.minimum(hmin, h.min(axis=1))
    return hmin


def table_log_penalty(hmin: np.ndarray, lambda_h: float, tolerance: float = 0.0) -> np.ndarray:
    """log c_h per particle: λ_h (h_min + tolerance) where negative, 0 elsewhere."""
    return lambda_h * np.minimum(np.asarray(hmin, np.float64) + tolerance, 0.0)
