"""Per-pixel ray casting of boxes, capsules and triangle meshes into colour/depth/id buffers (numba).

All geometry is in the camera frame (x right, y down, z forward; metres). The ray of pixel ``(u, v)``
is ``d = ((u - cx)/fx, (v - cy)/fy, 1)``, so the ray parameter of a hit equals its depth ``z``.

Every kernel works inside a pixel rectangle ``[u0, u1) × [v0, v1)`` and updates, where the hit is
nearer than what the buffers hold:

* ``depth`` (H×W float32): z of the nearest surface (``inf`` where nothing);
* ``cosang`` (H×W float32): |cos| of the angle between the surface normal and the viewing ray
  (used by the sensor model for grazing-angle dropouts);
* ``color`` (H×W×3 float32): shaded colour, 0..255 scale (Lambert: ``albedo·(ambient + diffuse·max(0, n·l))``
  with ``l`` the unit direction towards the light);
* ``ids`` (H×W int16): id of the nearest primitive's object (-1 background).

``hits[id]`` counts the pixels where the object is hit at all (occluded or not), which gives the
visible fraction of a part.
"""

from __future__ import annotations

import numba as nb
import numpy as np

_FM = {"nsz", "arcp", "contract", "afn", "reassoc"}
"""Fast-math flags without ``nnan``/``ninf``: the kernels rely on inf/NaN semantics."""


@nb.njit(cache=True, fastmath=_FM)
def _shade(color, v, u, albedo, nx, ny, nz, light, ambient, diffuse, factor):
    lam = nx * light[0] + ny * light[1] + nz * light[2]
    if lam < 0.0:
        lam = 0.0
    s = (ambient + diffuse * lam) * factor
    color[v, u, 0] = albedo[0] * s
    color[v, u, 1] = albedo[1] * s
    color[v, u, 2] = albedo[2] * s


@nb.njit(cache=True, fastmath=_FM)
def render_box(depth, cosang, color, ids, hits, fx, fy, cx, cy, R, t, half, albedo, light, ambient, diffuse,
               pid, u0, v0, u1, v1, edge_width, edge_dark):  # fmt: skip
    """Ray-cast a box (centre ``t``, rotation ``R`` body→camera, half extents ``half``) with darkened edges."""
    # ray origin (camera centre) in the box frame: o' = -Rᵀ t
    o0 = -(R[0, 0] * t[0] + R[1, 0] * t[1] + R[2, 0] * t[2])
    o1 = -(R[0, 1] * t[0] + R[1, 1] * t[1] + R[2, 1] * t[2])
    o2 = -(R[0, 2] * t[0] + R[1, 2] * t[1] + R[2, 2] * t[2])
    o = np.array([o0, o1, o2])
    dp = np.zeros(3)
    for v in range(v0, v1):
        yv = (v - cy) / fy
        for u in range(u0, u1):
            xu = (u - cx) / fx
            for j in range(3):
                dp[j] = R[0, j] * xu + R[1, j] * yv + R[2, j]
            tnear = -1e30
            tfar = 1e30
            axis = -1
            sign = 0.0
            miss = False
            for j in range(3):
                if abs(dp[j]) < 1e-12:
                    if abs(o[j]) > half[j]:
                        miss = True
                        break
                    continue
                ta = (-half[j] - o[j]) / dp[j]
                tb = (half[j] - o[j]) / dp[j]
                if ta > tb:
                    ta, tb = tb, ta
                if ta > tnear:
                    tnear = ta
                    axis = j
                    sign = -1.0 if dp[j] > 0 else 1.0
                if tb < tfar:
                    tfar = tb
            if miss or tnear > tfar or tnear <= 0.0 or axis < 0:
                continue
            hits[pid] += 1
            if tnear >= depth[v, u]:
                continue
            nx = R[0, axis] * sign
            ny = R[1, axis] * sign
            nz = R[2, axis] * sign
            dn = np.sqrt(xu * xu + yv * yv + 1.0)
            depth[v, u] = tnear
            cosang[v, u] = abs(nx * xu + ny * yv + nz) / dn
            ids[v, u] = pid
            # distance of the hit point to the nearest edge of its face
            emin = 1e30
            for j in range(3):
                if j != axis:
                    e = half[j] - abs(o[j] + tnear * dp[j])
                    if e < emin:
                        emin = e
            factor = 1.0
            if edge_width > 0.0 and emin < edge_width:
                factor = 1.0 - edge_dark * (1.0 - max(emin, 0.0) / edge_width)
            _shade(color, v, u, albedo, nx, ny, nz, light, ambient, diffuse, factor)


@nb.njit(cache=True, fastmath=_FM)
def render_capsule(depth, cosang, color, ids, hits, fx, fy, cx, cy, pa, pb, radius, albedo, light, ambient, diffuse,
                   pid, u0, v0, u1, v1):  # fmt: skip
    """Ray-cast a capsule (segment ``pa``–``pb`` swept by a sphere of ``radius``)."""
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


@nb.njit(cache=True, fastmath=_FM)
def render_triangles(depth, cosang, color, ids, hits, local, fx, fy, cx, cy, tris, normals, albedo, light, ambient,
                     diffuse, pid, u0, v0, u1, v1):  # fmt: skip
    """Rasterise camera-frame triangles ``tris`` [N,3,3] (outward ``normals`` [N,3]) of one object.

    ``local`` is a scratch float32 buffer of at least (v1-v0)×(u1-u0): the object's own z-buffer,
    used so that ``hits`` counts each covered pixel once.
    """
    hh = v1 - v0
    ww = u1 - u0
    for i in range(hh):
        for j in range(ww):
            local[i, j] = np.inf
    for k in range(tris.shape[0]):
        nx = normals[k, 0]
        ny = normals[k, 1]
        nz = normals[k, 2]
        if nx * tris[k, 0, 0] + ny * tris[k, 0, 1] + nz * tris[k, 0, 2] >= 0.0:
            continue  # back face
        if tris[k, 0, 2] < 0.05 or tris[k, 1, 2] < 0.05 or tris[k, 2, 2] < 0.05:
            continue
        pu0 = fx * tris[k, 0, 0] / tris[k, 0, 2] + cx
        pv0 = fy * tris[k, 0, 1] / tris[k, 0, 2] + cy
        pu1 = fx * tris[k, 1, 0] / tris[k, 1, 2] + cx
        pv1 = fy * tris[k, 1, 1] / tris[k, 1, 2] + cy
        pu2 = fx * tris[k, 2, 0] / tris[k, 2, 2] + cx
        pv2 = fy * tris[k, 2, 1] / tris[k, 2, 2] + cy
        area = (pu1 - pu0) * (pv2 - pv0) - (pu2 - pu0) * (pv1 - pv0)
        if abs(area) < 1e-12:
            continue
        bu0 = max(u0, int(np.floor(min(pu0, pu1, pu2))))
        bu1 = min(u1, int(np.ceil(max(pu0, pu1, pu2))) + 1)
        bv0 = max(v0, int(np.floor(min(pv0, pv1, pv2))))
        bv1 = min(v1, int(np.ceil(max(pv0, pv1, pv2))) + 1)
        iz0 = 1.0 / tris[k, 0, 2]
        iz1 = 1.0 / tris[k, 1, 2]
        iz2 = 1.0 / tris[k, 2, 2]
        for v in range(bv0, bv1):
            for u in range(bu0, bu1):
                w0 = ((pu1 - u) * (pv2 - v) - (pu2 - u) * (pv1 - v)) / area
                w1 = ((pu2 - u) * (pv0 - v) - (pu0 - u) * (pv2 - v)) / area
                w2 = 1.0 - w0 - w1
                if w0 < 0.0 or w1 < 0.0 or w2 < 0.0:
                    continue
                z = 1.0 / (w0 * iz0 + w1 * iz1 + w2 * iz2)
                if z < local[v - v0, u - u0]:
                    local[v - v0, u - u0] = z
                if z >= depth[v, u]:
                    continue
                xu = (u - cx) / fx
                yv = (v - cy) / fy
                dn = np.sqrt(xu * xu + yv * yv + 1.0)
                depth[v, u] = z
                cosang[v, u] = abs(nx * xu + ny * yv + nz) / dn
                ids[v, u] = pid
                _shade(color, v, u, albedo, nx, ny, nz, light, ambient, diffuse, 1.0)
    n = 0
    for i in range(hh):
        for j in range(ww):
            if local[i, j] < np.inf:
                n += 1
    hits[pid] += n


@nb.njit(cache=True, fastmath=_FM)
def apply_shadow(color, ids, table, mask, step, u0, v0, u1, v1):
    """Multiply background table pixels (``ids == -1`` and ``table``) in the rectangle by ``1 - mask``, with
    ``mask`` (≥ 0) sampled bilinearly at ``1/step`` resolution (mask pixel (i, j) is image pixel (v0 + i·step,
    u0 + j·step)). Returns the rectangle ``(u0, v0, u1, v1)`` (end-exclusive) of the pixels it changed (empty:
    ``u0 >= u1``). Pixels whose four mask samples are all 0 are skipped (their factor would be exactly 1)."""
    mh, mw = mask.shape
    inv = 1.0 / step
    # per mask row: first and last column with a non-zero value (first > last: none)
    first = np.full(mh, mw, np.int64)
    last = np.full(mh, -1, np.int64)
    for i in range(mh):
        for j in range(mw):
            if mask[i, j] != 0.0:
                if j < first[i]:
                    first[i] = j
                last[i] = j
    cu0, cv0, cu1, cv1 = u1, v1, u0, v0
    for v in range(v0, v1):
        fy = (v - v0) * inv
        i0 = min(int(fy), mh - 1)
        i1 = min(i0 + 1, mh - 1)
        ay = fy - i0
        jlo = min(first[i0], first[i1])
        jhi = max(last[i0], last[i1])
        if jhi < 0:
            continue
        # mask columns j0 = int((u - u0) / step) and j0 + 1 must reach [jlo, jhi]:
        # u - u0 in [step (jlo - 1), step (jhi + 1))
        ua = max(u0, u0 + step * (jlo - 1))
        ub = min(u1, u0 + step * (jhi + 1))
        for u in range(ua, ub):
            if ids[v, u] != -1 or not table[v, u]:
                continue
            fx = (u - u0) * inv
            j0 = min(int(fx), mw - 1)
            j1 = min(j0 + 1, mw - 1)
            ax = fx - j0
            m = (1.0 - ay) * ((1.0 - ax) * mask[i0, j0] + ax * mask[i0, j1]) + ay * (
                (1.0 - ax) * mask[i1, j0] + ax * mask[i1, j1]
            )
            if m > 0.002:
                f = 1.0 - m
                color[v, u, 0] *= f
                color[v, u, 1] *= f
                color[v, u, 2] *= f
                cu0 = min(cu0, u)
                cu1 = max(cu1, u + 1)
                cv0 = min(cv0, v)
                cv1 = max(cv1, v + 1)
    return cu0, cv0, cu1, cv1


@nb.njit(cache=True)
def restore_rects(rects, color_rects, depth, cosang, color, ids, bg_depth, bg_cos, bg_color):
    """Put the background back where the last frame drew: in the rectangles ``rects`` (int64 [n, 4] of
    ``u0, v0, u1, v1``, end-exclusive) every buffer (depth, cosang, colour from the background's, ids = -1), in
    ``color_rects`` the colour alone (shadows, blur). Each pixel is copied once however many rectangles cover it."""
    H, W = depth.shape
    geo = np.zeros(W, np.bool_)
    col = np.zeros(W, np.bool_)
    v_lo, v_hi = H, 0
    for r in (rects, color_rects):
        for i in range(r.shape[0]):
            v_lo = min(v_lo, max(r[i, 1], 0))
            v_hi = max(v_hi, min(r[i, 3], H))
    for v in range(v_lo, v_hi):
        geo[:] = False
        col[:] = False
        for i in range(rects.shape[0]):
            if rects[i, 1] <= v < rects[i, 3]:
                geo[max(rects[i, 0], 0) : min(rects[i, 2], W)] = True
        for i in range(color_rects.shape[0]):
            if color_rects[i, 1] <= v < color_rects[i, 3]:
                col[max(color_rects[i, 0], 0) : min(color_rects[i, 2], W)] = True
        u = 0
        while u < W:
            if not (geo[u] or col[u]):
                u += 1
                continue
            start, g = u, geo[u]
            while u < W and (geo[u] or col[u]) and geo[u] == g:
                u += 1
            for x in range(start, u):
                color[v, x, 0] = bg_color[v, x, 0]
                color[v, x, 1] = bg_color[v, x, 1]
                color[v, x, 2] = bg_color[v, x, 2]
            if g:
                for x in range(start, u):
                    depth[v, x] = bg_depth[v, x]
                    cosang[v, x] = bg_cos[v, x]
                    ids[v, x] = -1


def box_rect(R: np.ndarray, t: np.ndarray, half: np.ndarray, fx, fy, cx, cy, width, height, near=0.05):
    """Pixel rectangle (u0, v0, u1, v1), end-exclusive and clipped, covering a box; None if off-screen."""
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    pts = (signs * half) @ R.T + t
    return points_rect(pts, fx, fy, cx, cy, width, height, near)


def points_rect(pts: np.ndarray, fx, fy, cx, cy, width, height, near=0.05):
    """Clipped end-exclusive pixel rectangle covering the convex hull of camera-frame points; None if empty.

    A hull that reaches behind the near plane gets the whole image.
    """
    r = _points_rect(np.ascontiguousarray(pts, dtype=np.float64), fx, fy, cx, cy, width, height, near)
    return None if r[0] < 0 else (int(r[0]), int(r[1]), int(r[2]), int(r[3]))


@nb.njit(cache=True)
def _points_rect(pts, fx, fy, cx, cy, width, height, near):
    n = pts.shape[0]
    behind = 0
    umin = 1e30
    umax = -1e30
    vmin = 1e30
    vmax = -1e30
    for i in range(n):
        z = pts[i, 2]
        if z < near:
            behind += 1
            continue
        u = fx * pts[i, 0] / z + cx
        v = fy * pts[i, 1] / z + cy
        umin = min(umin, u)
        umax = max(umax, u)
        vmin = min(vmin, v)
        vmax = max(vmax, v)
    out = np.full(4, -1, np.int64)
    if behind == n:
        return out
    if behind > 0:
        out[0], out[1], out[2], out[3] = 0, 0, width, height
        return out
    u0 = max(0, int(np.floor(umin)))
    v0 = max(0, int(np.floor(vmin)))
    u1 = min(width, int(np.ceil(umax)) + 1)
    v1 = min(height, int(np.ceil(vmax)) + 1)
    if u0 >= u1 or v0 >= v1:
        return out
    out[0], out[1], out[2], out[3] = u0, v0, u1, v1
    return out


@nb.njit(cache=True)
def shadow_polygon(pts, n, d, light, fx, fy, cx, cy):
    """Project camera-frame ``pts`` along ``light`` onto the plane ``n·p + d = 0`` and into the image.

    Returns (uv [N, 2], mean height above the plane); uv is empty when a foot point is behind the camera.
    """
    m = pts.shape[0]
    denom = n[0] * light[0] + n[1] * light[1] + n[2] * light[2]
    uv = np.empty((m, 2))
    hsum = 0.0
    for i in range(m):
        h = n[0] * pts[i, 0] + n[1] * pts[i, 1] + n[2] * pts[i, 2] + d
        hsum += h
        k = max(h, 0.0) / denom
        x = pts[i, 0] - k * light[0]
        y = pts[i, 1] - k * light[1]
        z = pts[i, 2] - k * light[2]
        if z < 0.05:
            return np.empty((0, 2)), hsum / m
        uv[i, 0] = fx * x / z + cx
        uv[i, 1] = fy * y / z + cy
    return uv, hsum / m


@nb.njit(cache=True, fastmath=_FM)
def _bilinear(tex, x, y, c):
    """Bilinear sample of channel ``c`` of ``tex`` (H×W×C) at texel coordinates (x, y), clamped at the border."""
    h, w = tex.shape[0], tex.shape[1]
    x = min(max(x, 0.0), w - 1.0)
    y = min(max(y, 0.0), h - 1.0)
    i0 = min(int(y), h - 2) if h > 1 else 0
    j0 = min(int(x), w - 2) if w > 1 else 0
    ay = y - i0
    ax = x - j0
    i1 = min(i0 + 1, h - 1)
    j1 = min(j0 + 1, w - 1)
    return (1.0 - ay) * ((1.0 - ax) * tex[i0, j0, c] + ax * tex[i0, j1, c]) + ay * (
        (1.0 - ax) * tex[i1, j0, c] + ax * tex[i1, j1, c]
    )


@nb.njit(cache=True, fastmath=_FM)
def cast_background(depth, cosang, color, table, fx, fy, cx, cy, R, ct, tex, tpm, table_ext, floor_tex, fpm, floor_ext,
                    floor_drop, grey, table_shade, floor_shade, spot):  # fmt: skip
    """Ray-cast the textured table top (plane y = 0 of the table frame, ``table_ext`` = (x0, x1, z0, z1)) and the
    floor (y = -``floor_drop``) for every pixel of a camera at pose (``R``, ``ct``) in the table frame.

    Fills ``depth`` (inf where nothing), ``cosang``, ``color`` (albedo × shade: ``table_shade`` · (0.85 + 0.15 ·
    a Gaussian spot at (``spot[0]``, ``spot[1]``) of σ ``spot[2]``) on the table, ``floor_shade`` · (1 + 0.08 ·
    floor texture) · ``grey`` on the floor) and the ``table`` mask. Textures are indexed by table-frame (x, z):
    ``tex`` (rows z, cols x, ``tpm`` texels per metre from (x0, z0)), ``floor_tex`` (H×W×1, ``fpm`` texels per
    metre from (``floor_ext[0]``, ``floor_ext[1]``), repeated beyond its extent)."""
    h, w = depth.shape
    fh, fw = floor_tex.shape[0], floor_tex.shape[1]
    s2 = 2.0 * spot[2] * spot[2]
    for v in range(h):
        yv = (v - cy) / fy
        for u in range(w):
            xu = (u - cx) / fx
            d0 = R[0, 0] * xu + R[0, 1] * yv + R[0, 2]
            d1 = R[1, 0] * xu + R[1, 1] * yv + R[1, 2]
            d2 = R[2, 0] * xu + R[2, 1] * yv + R[2, 2]
            dn = np.sqrt(xu * xu + yv * yv + 1.0)
            depth[v, u] = np.inf
            cosang[v, u] = 1.0
            color[v, u, 0] = 0.0
            color[v, u, 1] = 0.0
            color[v, u, 2] = 0.0
            table[v, u] = False
            if abs(d1) < 1e-12:
                continue
            tt = -ct[1] / d1
            if tt > 0.0:
                px = ct[0] + tt * d0
                pz = ct[2] + tt * d2
                if table_ext[0] < px < table_ext[1] and table_ext[2] < pz < table_ext[3]:
                    f = table_shade * (0.85 + 0.15 * np.exp(-((px - spot[0]) ** 2 + (pz - spot[1]) ** 2) / s2))
                    mx = (px - table_ext[0]) * tpm
                    my = (pz - table_ext[2]) * tpm
                    for c in range(3):
                        color[v, u, c] = _bilinear(tex, mx, my, c) * f
                    depth[v, u] = tt
                    cosang[v, u] = abs(d1) / dn
                    table[v, u] = True
                    continue
            tf = (-floor_drop - ct[1]) / d1
            if tf > 0.0:
                px = ct[0] + tf * d0
                pz = ct[2] + tf * d2
                mx = ((px - floor_ext[0]) * fpm) % (fw - 1.0)
                my = ((pz - floor_ext[1]) * fpm) % (fh - 1.0)
                f = floor_shade * (1.0 + 0.08 * _bilinear(floor_tex, mx, my, 0))
                for c in range(3):
                    color[v, u, c] = grey[c] * f
                depth[v, u] = tf
                cosang[v, u] = abs(d1) / dn
