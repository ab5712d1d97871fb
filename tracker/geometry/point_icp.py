"""Compiled (numba) rigid point-to-plane ICP of the hand carry (:func:`tracker.filter.hand_carry.register_rigid`).

Every frame of a carry the hand patch (a few hundred points) is registered to the current hand points, up to
``carry_iterations`` rounds from each of two starts. Written with numpy and a KD-tree, a round cost a dozen small
array operations, two rotation conversions and a tree query; here a round is one compiled pass.

Nearest neighbours come from a uniform grid (:func:`build_grid`) whose cells are no smaller than the pairing bound
(2 cm): every point closer than the bound to a query lies in the query's cell or one of its 26 neighbours, so the
search is exact within the bound, which is all the registration asks (pairs farther than the bound are dropped and
the residual cost clips distances at the bound). The sums run in another order than numpy's and an equidistant
neighbour may be chosen differently, so results agree with the numpy form to rounding, not to the bit. The search
(:func:`_nearest`) tries the point's last nearest neighbour first, then the own cell, and scans a neighbour cell only
when its wall is nearer than the best so far (about 2x fewer distances); ties go to the earliest point in grid
order, so it returns exactly what the full scan of the 27 cells in grid order returned.

Units: metres, radians; points and rotation vectors in the camera frame.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def build_grid(pts: np.ndarray, cell: float):
    """Uniform grid over ``pts`` (P, 3) with cubic cells of side ``cell`` (m): (origin (3,), dims (3,) int64,
    start (C + 1,) int64, order (P,) int64); the points of cell k are ``order[start[k]:start[k + 1]]``, with cell
    k = (ix · dims[1] + iy) · dims[2] + iz of the cell indices i = floor((x − origin) / cell)."""
    m = pts.shape[0]
    lo = np.empty(3)
    hi = np.empty(3)
    for a in range(3):
        lo[a] = pts[0, a]
        hi[a] = pts[0, a]
    for j in range(1, m):
        for a in range(3):
            x = pts[j, a]
            if x < lo[a]:
                lo[a] = x
            if x > hi[a]:
                hi[a] = x
    dims = np.empty(3, np.int64)
    for a in range(3):
        dims[a] = int((hi[a] - lo[a]) / cell) + 1
    n_cells = dims[0] * dims[1] * dims[2]
    key = np.empty(m, np.int64)
    start = np.zeros(n_cells + 1, np.int64)
    for j in range(m):
        ix = min(int((pts[j, 0] - lo[0]) / cell), dims[0] - 1)
        iy = min(int((pts[j, 1] - lo[1]) / cell), dims[1] - 1)
        iz = min(int((pts[j, 2] - lo[2]) / cell), dims[2] - 1)
        key[j] = (ix * dims[1] + iy) * dims[2] + iz
        start[key[j] + 1] += 1
    for k in range(n_cells):
        start[k + 1] += start[k]
    fill = start[:-1].copy()
    order = np.empty(m, np.int64)
    for j in range(m):
        order[fill[key[j]]] = j
        fill[key[j]] += 1
    return lo, dims, start, order


CELL_SLACK = 1e-9
"""Slack (m) of the cell walls in :func:`_nearest`'s test of which neighbour cells can hold a point nearer than the
best so far: a point's cell comes from rounded divisions, so it may lie a rounding error (~1e-16 m here) outside its
cell's nominal box; the test treats every wall as this much nearer (a cell is skipped only when even then nothing in
it can beat the best)."""


@nb.njit(cache=True, inline="always")
def _cell_gap(q, lo, cell, i, side, n):
    """Distance (m) along one axis from coordinate ``q`` (in cell ``i`` of ``n``; −1 or ``n`` for a query just
    outside the grid) to the nearest wall of the neighbour cell on ``side`` (−1, 0, +1; 0 = its own cell: 0), less
    :data:`CELL_SLACK`, never below 0; a wall at the grid's outer edge counts as 0 (no cell lies beyond it)."""
    if side == 0:
        return 0.0
    if side < 0:
        g = q - (lo + i * cell) if i > 0 else 0.0
    else:
        g = (lo + (i + 1) * cell) - q if i + 1 < n else 0.0
    g -= CELL_SLACK
    return g if g > 0.0 else 0.0


@nb.njit(cache=True, inline="always")
def _scan_cell(spts, start, order, k, q0, q1, q2, best, best_d2, best_s):
    """:func:`_nearest`'s scan of grid cell ``k``: the best (index, squared distance, grid position) after it; a
    point replaces the best when strictly nearer, or as near and earlier in grid order."""
    for s in range(start[k], start[k + 1]):
        dx = q0 - spts[s, 0]
        dy = q1 - spts[s, 1]
        dz = q2 - spts[s, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < best_d2 or (d2 == best_d2 and best >= 0 and s < best_s):
            best, best_d2, best_s = order[s], d2, s
    return best, best_d2, best_s


@nb.njit(cache=True, inline="always")
def _nearest(spts, lo, dims, start, order, cell, bound2, q0, q1, q2, seed=-1):
    """Index of the point of ``pts`` nearest to (q0, q1, q2) among those closer than sqrt(bound2) (−1: none), its
    squared distance and its grid position (−1: none). ``spts`` are the points in grid order (``pts[order]``);
    ``seed``: a grid position to try first (e.g. the query's last nearest point; −1: none). ``bound2`` must not
    exceed ``cell``².

    The result is that of scanning the 27 cells around the query in grid order and keeping the first strictly
    nearer point (ties: the point earliest in grid order). Here the seed is taken first, then the query's own cell,
    then a neighbour cell only when its nearest wall (:func:`_cell_gap`) is nearer than the best so far; ties are
    resolved by grid position explicitly, so neither the seed nor the order changes the result."""
    fx = np.floor((q0 - lo[0]) / cell)
    fy = np.floor((q1 - lo[1]) / cell)
    fz = np.floor((q2 - lo[2]) / cell)
    best, best_d2, best_s = -1, bound2, -1
    if fx < -1.0 or fy < -1.0 or fz < -1.0 or fx > dims[0] or fy > dims[1] or fz > dims[2]:
        return best, best_d2, best_s
    if seed >= 0:
        # a seed farther than the bound is not a candidate (nor could the scan find it: it would lie beyond it)
        dx = q0 - spts[seed, 0]
        dy = q1 - spts[seed, 1]
        dz = q2 - spts[seed, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < best_d2:
            best, best_d2, best_s = order[seed], d2, seed
    ix, iy, iz = int(fx), int(fy), int(fz)
    # the own cell first
    if 0 <= ix < dims[0] and 0 <= iy < dims[1] and 0 <= iz < dims[2]:
        best, best_d2, best_s = _scan_cell(spts, start, order, (ix * dims[1] + iy) * dims[2] + iz, q0, q1, q2, best,
                                           best_d2, best_s)
    # then the neighbours in grid order, an axis's slab of cells skipped as soon as its wall is beyond the best
    for sx in range(-1, 2):
        ax = ix + sx
        if ax < 0 or ax >= dims[0]:
            continue
        gx = _cell_gap(q0, lo[0], cell, ix, sx, dims[0])
        gx2 = gx * gx
        if gx2 > best_d2:
            continue
        for sy in range(-1, 2):
            ay = iy + sy
            if ay < 0 or ay >= dims[1]:
                continue
            gy = _cell_gap(q1, lo[1], cell, iy, sy, dims[1])
            gxy2 = gx2 + gy * gy
            if gxy2 > best_d2:
                continue
            for sz in range(-1, 2):
                az = iz + sz
                if az < 0 or az >= dims[2] or (sx == 0 and sy == 0 and sz == 0):
                    continue
                gz = _cell_gap(q2, lo[2], cell, iz, sz, dims[2])
                if gxy2 + gz * gz > best_d2:
                    continue
                best, best_d2, best_s = _scan_cell(spts, start, order, (ax * dims[1] + ay) * dims[2] + az, q0, q1,
                                                   q2, best, best_d2, best_s)
    return best, best_d2, best_s


@nb.njit(cache=True)
def rotvec_matrix(w: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of rotation vector ``w`` (rad) (Rodrigues; series below 1e-9 rad)."""
    th = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    if th < 1e-9:
        a = 1.0 - th * th / 6.0
        b = 0.5 - th * th / 24.0
    else:
        a = np.sin(th) / th
        b = (1.0 - np.cos(th)) / (th * th)
    K = np.zeros((3, 3))
    K[0, 1], K[0, 2] = -w[2], w[1]
    K[1, 0], K[1, 2] = w[2], -w[0]
    K[2, 0], K[2, 1] = -w[1], w[0]
    R = a * K + b * (K @ K)
    for i in range(3):
        R[i, i] += 1.0
    return R


@nb.njit(cache=True)
def matrix_rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vector (rad, angle in [0, π]) of rotation matrix ``R`` (3, 3): the unit quaternion by Shepperd's
    method (the largest of the trace and the diagonal picks the stable formula), then 2 atan2(|v|, s) v / |v|
    (a series for angles below 1e-3 rad)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    q = np.empty(4)  # x, y, z, w
    if tr >= R[0, 0] and tr >= R[1, 1] and tr >= R[2, 2]:
        q[3] = 1.0 + tr
        q[0] = R[2, 1] - R[1, 2]
        q[1] = R[0, 2] - R[2, 0]
        q[2] = R[1, 0] - R[0, 1]
    else:
        i = 0
        if R[1, 1] > R[i, i]:
            i = 1
        if R[2, 2] > R[i, i]:
            i = 2
        j, k = (i + 1) % 3, (i + 2) % 3
        q[i] = 1.0 - tr + 2.0 * R[i, i]
        q[j] = R[j, i] + R[i, j]
        q[k] = R[k, i] + R[i, k]
        q[3] = R[k, j] - R[j, k]
    norm = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if q[3] < 0.0:
        norm = -norm
    for a in range(4):
        q[a] /= norm
    v = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2])
    angle = 2.0 * np.arctan2(v, q[3])
    if angle <= 1e-3:
        scale = 2.0 + angle * angle / 12.0 + 7.0 * angle**4 / 2880.0
    else:
        scale = angle / np.sin(angle / 2.0)
    out = np.empty(3)
    for a in range(3):
        out[a] = scale * q[a]
    return out


@nb.njit(cache=True)
def rigid_icp(rel: np.ndarray, c: np.ndarray, dst: np.ndarray, normals: np.ndarray, lo: np.ndarray, dims: np.ndarray,
              start: np.ndarray, order: np.ndarray, cell: float, bound: float, w0: np.ndarray, t0: np.ndarray,
              iterations: int, radius2: float, axis: np.ndarray, use_axis: bool):
    """Point-to-plane ICP of the offsets ``rel`` (M, 3) about centroid ``c`` onto ``dst`` (P, 3) with unit
    ``normals`` (P, 3), gridded by :func:`build_grid` (cell ``cell`` >= pairing bound ``bound``, m), from the
    motion (``w0`` rad, ``t0`` m): x' = R(w) rel + c + t. Each round pairs every moved point with its nearest
    ``dst`` point closer than ``bound`` (fewer than 6 pairs ends the rounds), takes one damped Gauss-Newton step
    (rotation damped by 1e-2 × the mean translational information × ``radius2``, translation by 1e-3 × its
    trace; with ``use_axis`` the rotation is about unit ``axis`` only) and stops early once the step is below
    5e-5 m and 1e-4 rad. Returns (w, t, cost): cost is the mean distance of the moved points to their nearest
    ``dst`` point, clipped at ``bound``."""
    m = rel.shape[0]
    nr = 1 if use_axis else 3
    nv = nr + 3
    bound2 = bound * bound
    w = w0.copy()
    t = t0.copy()
    row = np.empty(6)
    spts = np.empty((order.shape[0], 3))  # the points in grid order: a cell's points side by side
    for s in range(order.shape[0]):
        for a in range(3):
            spts[s, a] = dst[order[s], a]
    last = np.full(m, -1, np.int64)  # per moved point, the grid position of its nearest point in the last round
    for _ in range(max(iterations, 1)):
        R = rotvec_matrix(w)
        A = np.zeros((nv, nv))
        b = np.zeros(nv)
        pairs = 0
        for i in range(m):
            r0, r1, r2 = rel[i, 0], rel[i, 1], rel[i, 2]
            q0 = R[0, 0] * r0 + R[0, 1] * r1 + R[0, 2] * r2
            q1 = R[1, 0] * r0 + R[1, 1] * r1 + R[1, 2] * r2
            q2 = R[2, 0] * r0 + R[2, 1] * r1 + R[2, 2] * r2
            m0, m1, m2 = q0 + c[0] + t[0], q1 + c[1] + t[1], q2 + c[2] + t[2]
            j, _d2, last[i] = _nearest(spts, lo, dims, start, order, cell, bound2, m0, m1, m2, last[i])
            if j < 0:
                continue
            pairs += 1
            n0, n1, n2 = normals[j, 0], normals[j, 1], normals[j, 2]
            res = n0 * (dst[j, 0] - m0) + n1 * (dst[j, 1] - m1) + n2 * (dst[j, 2] - m2)
            j0 = q1 * n2 - q2 * n1
            j1 = q2 * n0 - q0 * n2
            j2 = q0 * n1 - q1 * n0
            if use_axis:
                row[0] = j0 * axis[0] + j1 * axis[1] + j2 * axis[2]
            else:
                row[0], row[1], row[2] = j0, j1, j2
            row[nr], row[nr + 1], row[nr + 2] = n0, n1, n2
            for a in range(nv):
                b[a] += row[a] * res
                for e in range(a, nv):
                    A[a, e] += row[a] * row[e]
        if pairs < 6:
            break
        for a in range(nv):
            for e in range(a):
                A[a, e] = A[e, a]
        tr = A[nr, nr] + A[nr + 1, nr + 1] + A[nr + 2, nr + 2]
        lam = 1e-2 * tr / 3.0
        for a in range(nr):
            A[a, a] += lam * radius2
        for a in range(nr, nv):
            A[a, a] += 1e-3 * tr
        x = np.linalg.solve(A, b)
        dw = np.empty(3)
        if use_axis:
            for a in range(3):
                dw[a] = x[0] * axis[a]
        else:
            for a in range(3):
                dw[a] = x[a]
        w = matrix_rotvec(rotvec_matrix(dw) @ R)
        step_t = np.sqrt(x[nr] ** 2 + x[nr + 1] ** 2 + x[nr + 2] ** 2)
        for a in range(3):
            t[a] += x[nr + a]
        if step_t < 5e-5 and np.sqrt(dw[0] ** 2 + dw[1] ** 2 + dw[2] ** 2) < 1e-4:
            break
    R = rotvec_matrix(w)
    total = 0.0
    for i in range(m):
        r0, r1, r2 = rel[i, 0], rel[i, 1], rel[i, 2]
        m0 = R[0, 0] * r0 + R[0, 1] * r1 + R[0, 2] * r2 + c[0] + t[0]
        m1 = R[1, 0] * r0 + R[1, 1] * r1 + R[1, 2] * r2 + c[1] + t[1]
        m2 = R[2, 0] * r0 + R[2, 1] * r1 + R[2, 2] * r2 + c[2] + t[2]
        j, d2, _s = _nearest(spts, lo, dims, start, order, cell, bound2, m0, m1, m2, last[i])
        total += np.sqrt(d2) if j >= 0 else bound
    return w, t, total / max(m, 1)
