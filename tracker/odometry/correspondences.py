"""Numba kernels of the dense alignment: per-point correspondences, residuals and Jacobian rows of the photometric
and point-to-plane terms for one Gauss-Newton iteration (see :mod:`.dense_alignment` for the formulation).

Frames: keyframe points in the keyframe camera frame; ``T_ck`` maps them into the current camera frame
(4×4, metres). Pixels: column u, row v, pixel centres at integers.
"""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)
def photometric_terms(points, values, jac, T_ck, gray, mask, fx, fy, cx, cy, ref_out, cur_out, jac_out):
    """For every keyframe point seen in the current image on an unmasked pixel: its keyframe grey value
    (``ref_out``), the current image's bilinear grey value where it projects (``cur_out``) and its Jacobian row
    (``jac_out``). Returns how many were written."""
    h, w = gray.shape
    n = 0
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        xc = T_ck[0, 0] * x + T_ck[0, 1] * y + T_ck[0, 2] * z + T_ck[0, 3]
        yc = T_ck[1, 0] * x + T_ck[1, 1] * y + T_ck[1, 2] * z + T_ck[1, 3]
        zc = T_ck[2, 0] * x + T_ck[2, 1] * y + T_ck[2, 2] * z + T_ck[2, 3]
        if zc <= 0.05:
            continue
        u = fx * xc / zc + cx
        v = fy * yc / zc + cy
        if u < 0.0 or v < 0.0 or u > w - 1.001 or v > h - 1.001:
            continue
        if mask[int(v + 0.5), int(u + 0.5)]:
            continue
        u0, v0 = int(u), int(v)
        a, b = u - u0, v - v0
        val = ((1 - a) * (1 - b) * gray[v0, u0] + a * (1 - b) * gray[v0, u0 + 1]
               + (1 - a) * b * gray[v0 + 1, u0] + a * b * gray[v0 + 1, u0 + 1])
        ref_out[n] = values[i]
        cur_out[n] = val
        for k in range(6):
            jac_out[n, k] = jac[i, k]
        n += 1
    return n


@nb.njit(cache=True, nogil=True)
def geometric_terms(points, normals, T_ck, T_kc, depth, mask, fx, fy, cx, cy, max_dist, r_out, jac_out):
    """Point-to-plane residuals ``n·(T_kc q − p)`` with projective association and their Jacobian rows
    ``[n, q × n]``. Returns ``(written, seen)``: correspondences kept (closer than ``max_dist``) and keyframe
    points that landed on a valid, unmasked depth pixel."""
    h, w = depth.shape
    n = 0
    seen = 0
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        xc = T_ck[0, 0] * x + T_ck[0, 1] * y + T_ck[0, 2] * z + T_ck[0, 3]
        yc = T_ck[1, 0] * x + T_ck[1, 1] * y + T_ck[1, 2] * z + T_ck[1, 3]
        zc = T_ck[2, 0] * x + T_ck[2, 1] * y + T_ck[2, 2] * z + T_ck[2, 3]
        if zc <= 0.05:
            continue
        ui = int(fx * xc / zc + cx + 0.5)
        vi = int(fy * yc / zc + cy + 0.5)
        if ui < 0 or vi < 0 or ui >= w or vi >= h:
            continue
        d = depth[vi, ui]
        if not (d > 0.0) or mask[vi, ui]:
            continue
        seen += 1
        qx = (ui - cx) * d / fx
        qy = (vi - cy) * d / fy
        qz = d
        kx = T_kc[0, 0] * qx + T_kc[0, 1] * qy + T_kc[0, 2] * qz + T_kc[0, 3]
        ky = T_kc[1, 0] * qx + T_kc[1, 1] * qy + T_kc[1, 2] * qz + T_kc[1, 3]
        kz = T_kc[2, 0] * qx + T_kc[2, 1] * qy + T_kc[2, 2] * qz + T_kc[2, 3]
        dx, dy, dz = kx - x, ky - y, kz - z
        if dx * dx + dy * dy + dz * dz > max_dist * max_dist:
            continue
        nx, ny, nz = normals[i, 0], normals[i, 1], normals[i, 2]
        r_out[n] = nx * dx + ny * dy + nz * dz
        jac_out[n, 0] = nx
        jac_out[n, 1] = ny
        jac_out[n, 2] = nz
        jac_out[n, 3] = ky * nz - kz * ny
        jac_out[n, 4] = kz * nx - kx * nz
        jac_out[n, 5] = kx * ny - ky * nx
        n += 1
    return n, seen


def empty_buffers(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scratch arrays for ``n`` points: two value vectors and a Jacobian block."""
    return np.empty(n), np.empty(n), np.empty((n, 6))


@nb.njit(cache=True, nogil=True)
def _select(a, k):
    """The ``k``-th smallest of the finite values ``a`` (rearranged in place: every value before index ``k`` is then at
    most ``a[k]``). Quickselect with a branch-free partition (median-of-three pivot; a comparison's outcome moves an
    index instead of taking a branch, which a random residual mispredicts half the time: twice as fast as numba's
    ``np.median`` on a thousand residuals); small ranges, and ranges a few rounds hardly shrank (many equal values),
    are sorted."""
    lo, hi = 0, a.shape[0] - 1
    poor = 0
    while hi - lo > 16:
        size = hi - lo
        mid = (lo + hi) >> 1
        x, y, z = a[lo], a[mid], a[hi]
        if y < x:
            x, y = y, x
        if z < y:
            y = x if z < x else z
        if a[mid] == y:  # the pivot to the end
            a[mid], a[hi] = a[hi], a[mid]
        elif a[lo] == y:
            a[lo], a[hi] = a[hi], a[lo]
        p = a[hi]
        j = lo
        for i in range(lo, hi):  # a[lo:j] < p <= a[j:i]
            v = a[i]
            a[i] = a[j]
            a[j] = v
            j += v < p
        a[hi] = a[j]
        a[j] = p
        if k == j:
            return p
        if k < j:
            hi = j - 1
        else:
            lo = j + 1
        if 8 * (hi - lo) > 7 * size:  # little progress (e.g. many values equal to the pivot)
            poor += 1
            if poor > 3:
                break
    a[lo:hi + 1].sort()
    return a[k]


@nb.njit(cache=True, nogil=True)
def _median(a):
    """The median of the finite values ``a`` (rearranged in place), the value numba's ``np.median`` gives: the middle
    one, or the mean ``(lower + upper) / 2`` of the two middle ones."""
    n = a.shape[0]
    if n == 0:
        return np.nan
    half = n >> 1
    upper = _select(a, half)
    if n & 1:
        return upper
    lower = a[0]
    for i in range(1, half):
        lower = max(lower, a[i])
    return (lower + upper) / 2


@nb.njit(cache=True, nogil=True)
def _robust_scale(r, n, max_samples, floor):
    """1.4826 × the median absolute deviation of ``r[:n]`` (at most ``max_samples`` of them, an even stride; finite
    residuals), not below ``floor``."""
    if n == 0:
        return floor
    stride = 1 if n <= max_samples else -(-n // max_samples)
    s = r[0:n:stride].copy()
    med = _median(s.copy())
    for i in range(s.shape[0]):
        s[i] = abs(s[i] - med)
    return max(floor, 1.4826 * _median(s))


@nb.njit(cache=True, nogil=True)
def _accumulate(r, jac, n, sigma, scale, tukey, threshold, huber, H, g):
    """Add the robustly weighted rows ``0..n-1`` (residuals ``r``, Jacobian rows ``jac``) to the normal equations
    ``H`` (6×6) and ``g`` (6): weight ``scale / sigma²`` times Huber's (``threshold`` = its k) or Tukey's
    (``tukey``; ``threshold`` = its c) weight of ``r / sigma``. Returns the rows within ``huber`` robust standard
    deviations (inliers)."""
    inl = 0
    base = scale / (sigma * sigma)
    acc = np.zeros(27)  # the 21 entries of H's upper triangle, then g
    for i in range(n):
        x = abs(r[i]) / sigma
        if tukey:
            y = min(x / threshold, 1.0)
            w = (1.0 - y * y) ** 2
        else:
            w = 1.0 if x <= threshold else threshold / max(x, 1e-12)
        if x <= huber:
            inl += 1
        w *= base
        if w == 0.0:
            continue
        j0, j1, j2, j3, j4, j5 = jac[i, 0], jac[i, 1], jac[i, 2], jac[i, 3], jac[i, 4], jac[i, 5]
        w0, w1, w2, w3, w4, w5 = w * j0, w * j1, w * j2, w * j3, w * j4, w * j5
        acc[0] += w0 * j0
        acc[1] += w0 * j1
        acc[2] += w0 * j2
        acc[3] += w0 * j3
        acc[4] += w0 * j4
        acc[5] += w0 * j5
        acc[6] += w1 * j1
        acc[7] += w1 * j2
        acc[8] += w1 * j3
        acc[9] += w1 * j4
        acc[10] += w1 * j5
        acc[11] += w2 * j2
        acc[12] += w2 * j3
        acc[13] += w2 * j4
        acc[14] += w2 * j5
        acc[15] += w3 * j3
        acc[16] += w3 * j4
        acc[17] += w3 * j5
        acc[18] += w4 * j4
        acc[19] += w4 * j5
        acc[20] += w5 * j5
        ri = r[i]
        acc[21] += w0 * ri
        acc[22] += w1 * ri
        acc[23] += w2 * ri
        acc[24] += w3 * ri
        acc[25] += w4 * ri
        acc[26] += w5 * ri
    k = 0
    for a in range(6):
        for b in range(a, 6):
            H[a, b] += acc[k]
            k += 1
        g[a] += acc[21 + a]
    return inl


@nb.njit(cache=True, nogil=True)
def symmetrise(H):
    """Copy the upper triangle of a square matrix into its lower triangle (in place)."""
    for a in range(6):
        for b in range(a):
            H[a, b] = H[b, a]


@nb.njit(cache=True, nogil=True)
def photometric_system(points, values, jac, T_ck, gray, mask, fx, fy, cx, cy, min_sigma, max_samples, weight,
                       tukey, threshold, huber, ref, cur, jac_buf, H, g):
    """The photometric term of one Gauss-Newton iteration added to ``H``, ``g`` (see :mod:`.dense_alignment`):
    correspondences (:func:`photometric_terms`), a global gain and offset ``ref ≈ a·cur + b`` (``a`` clipped to
    0.7–1.3), the robust scale of the residuals and their weighted rows. ``ref``, ``cur``, ``jac_buf``: scratch
    of the keyframe points' length. Returns the inliers (0 when fewer than 10 points are seen: nothing added)."""
    n = photometric_terms(points, values, jac, T_ck, gray, mask, fx, fy, cx, cy, ref, cur, jac_buf)
    if n < 10:
        return 0
    vm = 0.0
    rm = 0.0
    for i in range(n):
        vm += cur[i]
        rm += ref[i]
    vm /= n
    rm /= n
    var = 0.0
    cov = 0.0
    for i in range(n):
        var += (cur[i] - vm) ** 2
        cov += (cur[i] - vm) * (ref[i] - rm)
    var /= n
    cov /= n
    a = min(max(cov / var, 0.7), 1.3) if var > 1e-6 else 1.0
    b = rm - a * vm
    for i in range(n):
        ref[i] = ref[i] - (a * cur[i] + b)  # residuals, in place
    s = _robust_scale(ref, n, max_samples, min_sigma)
    inl = _accumulate(ref, jac_buf, n, s, weight, tukey, threshold, huber, H, g)
    return inl


@nb.njit(cache=True, nogil=True)
def geometric_system(points, normals, T_ck, T_kc, depth, mask, fx, fy, cx, cy, max_dist, min_sigma, max_samples,
                     tukey, threshold, huber, r_buf, jac_buf, H, g):
    """The point-to-plane term of one Gauss-Newton iteration added to ``H``, ``g`` (:func:`geometric_terms`, robust
    scale, weighted rows). Returns ``(inliers, seen)``; nothing is added when fewer than 10 correspondences are
    kept (inliers 0)."""
    n, seen = geometric_terms(points, normals, T_ck, T_kc, depth, mask, fx, fy, cx, cy, max_dist, r_buf, jac_buf)
    if n < 10:
        return 0, seen
    s = _robust_scale(r_buf, n, max_samples, min_sigma)
    inl = _accumulate(r_buf, jac_buf, n, s, 1.0, tukey, threshold, huber, H, g)
    return inl, seen
