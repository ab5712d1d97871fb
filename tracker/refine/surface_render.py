"""One-pose z-buffer rendering of every part into a strided label/depth/normal buffer (numba).

The dense-depth refinement (:mod:`tracker.refine.dense_depth`) needs, per part and frame, the surface points
that the camera sees at the current estimate together with their normals, and which pixels belong to which part
(a pixel counts for at most one part: the nearest at its estimate). This module renders all parts once per frame
at their single estimated poses on a grid of pixels ``(u0 + i·s, v0 + j·s)`` (stride ``s`` px) over a rectangle of
the image:

* boxes are ray-cast exactly (slab test), giving the hit face's normal;
* meshes are rasterised triangle by triangle (screen-space barycentric test, depth interpolated as 1/z, which is
  exact for planar triangles under perspective), with the face normal turned toward the camera (meshes may be
  open, double-sided surfaces with no consistent winding).

Camera frame: x right, y down, z forward (metres); pixel ``(u, v)`` has the ray ``((u−cx)/fx, (v−cy)/fy, 1)`` so
a hit's ray parameter is its depth ``z``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numba as nb
import numpy as np

from tracker.geometry.camera import Intrinsics
from tracker.geometry.fma import fma


@nb.njit(cache=True, inline="always")
def _box_origin(R, t, center):
    """The camera's centre in a box's frame, relative to the box centre: ``o = Rᵀ(0 − t) − center`` (3,)."""
    o = np.empty(3)
    for j in range(3):
        o[j] = -(R[0, j] * t[0] + R[1, j] * t[1] + R[2, j] * t[2]) - center[j]
    return o


@nb.njit(cache=True, inline="always")
def _box_ray(o, R, half, xu, yv):
    """First hit of the ray ``(xu, yv, 1)`` (camera frame) with a box (slab test; ``o`` from :func:`_box_origin`):
    ``(depth, axis, sign)`` — the hit face is body axis ``axis`` with outward sign ``sign`` — or ``(inf, −1, 0)``
    when it misses (or hits within 0.1 mm of the camera)."""
    tnear = -1e30
    tfar = 1e30
    axis = -1
    sign = 0.0
    for j in range(3):
        dj = R[0, j] * xu + R[1, j] * yv + R[2, j]
        if abs(dj) < 1e-12:
            if o[j] < -half[j] or o[j] > half[j]:
                return np.inf, -1, 0.0
            continue
        ta = (-half[j] - o[j]) / dj
        tb = (half[j] - o[j]) / dj
        sg = -1.0
        if ta > tb:
            ta, tb = tb, ta
            sg = 1.0
        if ta > tnear:
            tnear = ta
            axis = j
            sign = sg
        if tb < tfar:
            tfar = tb
    if axis < 0 or tnear > tfar or tnear <= 1e-4:
        return np.inf, -1, 0.0
    return tnear, axis, sign


@nb.njit(cache=True)
def _box_corners_px(R, t, center, half, fx, fy, cx, cy):
    """Pixels ``(u[8], v[8])`` of a box's corners (numbered as the loops over ±x, ±y, ±z visit them, z fastest) and
    whether a corner lies within 1 mm of the camera plane or behind it (its pixel is then NaN)."""
    cu = np.empty(8)
    cv = np.empty(8)
    near = False
    c = 0
    for sx in (-1.0, 1.0):
        for sy in (-1.0, 1.0):
            for sz in (-1.0, 1.0):
                bx, by, bz = center[0] + sx * half[0], center[1] + sy * half[1], center[2] + sz * half[2]
                x = R[0, 0] * bx + R[0, 1] * by + R[0, 2] * bz + t[0]
                y = R[1, 0] * bx + R[1, 1] * by + R[1, 2] * bz + t[1]
                z = R[2, 0] * bx + R[2, 1] * by + R[2, 2] * bz + t[2]
                if z < 1e-3:
                    near = True
                    cu[c], cv[c] = np.nan, np.nan
                else:
                    cu[c], cv[c] = fx * x / z + cx, fy * y / z + cy
                c += 1
    return cu, cv, near


@nb.njit(cache=True)
def _box_bounds(R, t, center, half, fx, fy, cx, cy):
    """Projected rectangle ``(umin, umax, vmin, vmax)`` (pixels) of a box's 8 corners and whether a corner lies
    within 1 mm of the camera plane or behind it (then the rectangle holds the other corners only)."""
    cu, cv, near = _box_corners_px(R, t, center, half, fx, fy, cx, cy)
    umin, umax, vmin, vmax = np.inf, -np.inf, np.inf, -np.inf
    for c in range(8):
        if cu[c] == cu[c]:
            umin, umax = min(umin, cu[c]), max(umax, cu[c])
            vmin, vmax = min(vmin, cv[c]), max(vmax, cv[c])
    return umin, umax, vmin, vmax, near


@nb.njit(cache=True)
def _clip_window(umin, umax, vmin, vmax, u0, v0, nu, nv):
    """Cells ``(i0, i1, j0, j1)`` (inclusive) of an ``nu`` × ``nv`` grid at pixel ``(u0, v0)``, stride 1, that hold the
    pixel rectangle ``umin..umax`` × ``vmin..vmax`` widened by 2 cells (a part's pixels and their 4-neighbours);
    empty (``i0 > i1``) when it misses the grid."""
    lo_u, hi_u = np.floor(umin - u0) - 2.0, np.ceil(umax - u0) + 2.0
    lo_v, hi_v = np.floor(vmin - v0) - 2.0, np.ceil(vmax - v0) + 2.0
    if nu <= 0 or nv <= 0 or hi_u < 0.0 or hi_v < 0.0 or lo_u > nu - 1 or lo_v > nv - 1:
        return 0, -1, 0, -1
    return int(max(lo_u, 0.0)), int(min(hi_u, nu - 1.0)), int(max(lo_v, 0.0)), int(min(hi_v, nv - 1.0))


@nb.njit(cache=True)
def _render_box(zbuf, label, normal, u0, v0, s, fx, fy, cx, cy, R, t, center, half, obj, wi0, wj0):
    """Ray-cast one box (body → camera ``R``, ``t``; body-frame ``center`` and ``half`` extents) into the grid.

    The buffers hold the window of grid cells ``(wj0 + j, wi0 + i)`` (``0, 0`` and the whole grid's shape: all of
    it); cells outside the window are not drawn. An empty ``normal`` (shape ``(0, 0, 3)``) is not written."""
    nv, nu = zbuf.shape
    with_normal = normal.shape[0] > 0
    o = _box_origin(R, t, center)
    # only the grid cells within the box's projected corners (and a cell around them) can see it; the whole grid
    # when a corner lies near or behind the camera plane
    imin, imax, jmin, jmax = wi0, wi0 + nu - 1, wj0, wj0 + nv - 1
    umin, umax, vmin, vmax, near = _box_bounds(R, t, center, half, fx, fy, cx, cy)
    if not near:
        imin = max(imin, int(np.floor((umin - u0) / s)) - 1)
        imax = min(imax, int(np.ceil((umax - u0) / s)) + 1)
        jmin = max(jmin, int(np.floor((vmin - v0) / s)) - 1)
        jmax = min(jmax, int(np.ceil((vmax - v0) / s)) + 1)
    for jj in range(jmin, jmax + 1):
        yv = (v0 + jj * s - cy) / fy
        for ii in range(imin, imax + 1):
            xu = (u0 + ii * s - cx) / fx
            tnear, axis, sign = _box_ray(o, R, half, xu, yv)
            if axis < 0:
                continue
            bj, bi = jj - wj0, ii - wi0
            if tnear < zbuf[bj, bi]:
                zbuf[bj, bi] = tnear
                label[bj, bi] = obj
                if with_normal:  # outward face normal: body axis ``axis`` with sign opposite to the ray's component
                    for r in range(3):
                        normal[bj, bi, r] = R[r, axis] * sign


@nb.njit(cache=True)
def _render_mesh(zbuf, label, normal, u0, v0, s, fx, fy, cx, cy, R, t, vertices, faces, obj, wi0, wj0):
    """Rasterise one triangle mesh (body → camera ``R``, ``t``) into the grid (normals facing the camera); the
    window ``wi0``, ``wj0`` and an empty ``normal`` as in :func:`_render_box`."""
    nv, nu = zbuf.shape
    with_normal = normal.shape[0] > 0
    nvert = vertices.shape[0]
    cam = np.empty((nvert, 3))
    for a in range(nvert):
        for r in range(3):
            cam[a, r] = R[r, 0] * vertices[a, 0] + R[r, 1] * vertices[a, 1] + R[r, 2] * vertices[a, 2] + t[r]
    for f in range(faces.shape[0]):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        z0, z1, z2 = cam[i0, 2], cam[i1, 2], cam[i2, 2]
        if z0 < 1e-3 or z1 < 1e-3 or z2 < 1e-3:
            continue
        # grid coordinates of the projected vertices
        x0 = (fx * cam[i0, 0] / z0 + cx - u0) / s
        y0 = (fy * cam[i0, 1] / z0 + cy - v0) / s
        x1 = (fx * cam[i1, 0] / z1 + cx - u0) / s
        y1 = (fy * cam[i1, 1] / z1 + cy - v0) / s
        x2 = (fx * cam[i2, 0] / z2 + cx - u0) / s
        y2 = (fy * cam[i2, 1] / z2 + cy - v0) / s
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if abs(area) < 1e-12:
            continue
        imin = max(int(np.ceil(min(x0, x1, x2))), wi0)
        imax = min(int(np.floor(max(x0, x1, x2))), wi0 + nu - 1)
        jmin = max(int(np.ceil(min(y0, y1, y2))), wj0)
        jmax = min(int(np.floor(max(y0, y1, y2))), wj0 + nv - 1)
        if imin > imax or jmin > jmax:
            continue
        # face normal (camera frame), turned toward the camera
        ax, ay, az = cam[i1, 0] - cam[i0, 0], cam[i1, 1] - cam[i0, 1], cam[i1, 2] - cam[i0, 2]
        bx, by, bz = cam[i2, 0] - cam[i0, 0], cam[i2, 1] - cam[i0, 1], cam[i2, 2] - cam[i0, 2]
        nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        nn = np.sqrt(nx * nx + ny * ny + nz * nz)
        if nn < 1e-15:
            continue
        nx, ny, nz = nx / nn, ny / nn, nz / nn
        if nx * cam[i0, 0] + ny * cam[i0, 1] + nz * cam[i0, 2] > 0.0:
            nx, ny, nz = -nx, -ny, -nz
        iz0, iz1, iz2 = 1.0 / z0, 1.0 / z1, 1.0 / z2
        for jj in range(jmin, jmax + 1):
            for ii in range(imin, imax + 1):
                w0 = ((x1 - ii) * (y2 - jj) - (x2 - ii) * (y1 - jj)) / area
                w1 = ((x2 - ii) * (y0 - jj) - (x0 - ii) * (y2 - jj)) / area
                w2 = 1.0 - w0 - w1
                if w0 < -1e-9 or w1 < -1e-9 or w2 < -1e-9:
                    continue
                z = 1.0 / (w0 * iz0 + w1 * iz1 + w2 * iz2)
                bj, bi = jj - wj0, ii - wi0
                if z < zbuf[bj, bi]:
                    zbuf[bj, bi] = z
                    label[bj, bi] = obj
                    if with_normal:
                        normal[bj, bi, 0] = nx
                        normal[bj, bi, 1] = ny
                        normal[bj, bi, 2] = nz


@dataclass
class SurfaceRender:
    """Strided render of several parts: grid pixel ``(i, j)`` is image pixel ``(u0 + i·stride, v0 + j·stride)``.

    ``depth`` (nv, nu) metres (inf where nothing), ``label`` (nv, nu) part index (−1 where nothing), ``normal``
    (nv, nu, 3) unit surface normals facing the camera (camera frame).
    """

    u0: int
    v0: int
    stride: int
    depth: np.ndarray
    label: np.ndarray
    normal: np.ndarray
    boxes: np.ndarray | None = field(default=None, repr=False)
    """Per label (part index) the grid rows and columns ``(j0, j1, i0, i1)`` (inclusive) its cells span (j0 > j1:
    none), made on the first :meth:`points_of` (the labels are not changed after the render)."""

    def points_of(self, obj: int, intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
        """Visible surface points (camera frame, (M, 3)) of part ``obj`` and their normals (M, 3), in row-major
        order of their pixels."""
        return self._points_in(obj, intrinsics, None)

    def body_points_of(self, obj: int, intrinsics: Intrinsics, R: np.ndarray,
                       t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`points_of` in the body frame of the pose ``(R, t)`` (body → camera): ``(pts − t) @ R`` and
        ``nrm @ R``, each entry rounded as numpy's BLAS product of these shapes rounds it here
        (``fma(d2, r2, fma(d1, r1, d0·r0))``, :mod:`tracker.geometry.fma`), in one pass without the camera-frame
        arrays."""
        return self._points_in(obj, intrinsics, (R, t))

    def _points_in(self, obj: int, intrinsics: Intrinsics, pose: tuple | None) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`points_of` (``pose`` None) or :meth:`body_points_of` (``pose`` = ``(R, t)``)."""
        if self.boxes is None:
            self.boxes = _label_boxes(self.label)
        if obj < 0 or obj >= self.boxes.shape[0]:
            return np.empty((0, 3)), np.empty((0, 3))
        j0, j1, i0, i1 = (int(x) for x in self.boxes[obj])
        R, t = _NO_POSE if pose is None else (np.ascontiguousarray(x, np.float64) for x in pose)
        return _cell_points(self.label, np.asarray(self.depth, np.float64), np.asarray(self.normal, np.float64), obj,
                            self.u0, self.v0, self.stride, intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy,
                            j0, j1, i0, i1, R, t, pose is not None)


@nb.njit(cache=True)
def _label_boxes(label):
    """Per label 0 … max(label) the rows and columns ``(j0, j1, i0, i1)`` its cells span (j0 > j1 for a label with no
    cell), in one pass over the grid."""
    nv, nu = label.shape
    top = -1
    for j in range(nv):
        for i in range(nu):
            if label[j, i] > top:
                top = label[j, i]
    out = np.empty((top + 1, 4), np.int64)
    for o in range(top + 1):
        out[o, 0], out[o, 1], out[o, 2], out[o, 3] = nv, -1, nu, -1
    for j in range(nv):
        for i in range(nu):
            o = label[j, i]
            if o >= 0:
                out[o, 0] = min(out[o, 0], j)
                out[o, 1] = max(out[o, 1], j)
                out[o, 2] = min(out[o, 2], i)
                out[o, 3] = max(out[o, 3], i)
    return out


@nb.njit(cache=True)
def _cell_points(label, depth, normal, obj, u0, v0, stride, fx, fy, cx, cy, j0, j1, i0, i1, R, t, to_body):
    """:meth:`SurfaceRender.points_of` (``to_body`` False; ``R``, ``t`` unused) and
    :meth:`~SurfaceRender.body_points_of` (True) in one pass: the cells labelled ``obj``, back-projected
    (``x = (u − cx)/fx · z``, ``y = (v − cy)/fy · z``), and their normals, camera frame, or taken into the body frame
    of ``(R, t)`` as they are formed (``(p − t) @ R``, ``n @ R``, each entry ``fma(d2, r2, fma(d1, r1, d0·r0))``);
    only the rows ``j0 … j1`` and columns ``i0 … i1`` (inclusive) are visited, which hold all of them."""
    n = 0
    for j in range(j0, j1 + 1):
        for i in range(i0, i1 + 1):
            if label[j, i] == obj:
                n += 1
    pts = np.empty((n, 3))
    nrm = np.empty((n, 3))
    m = 0
    for j in range(j0, j1 + 1):
        v = v0 + j * stride
        for i in range(i0, i1 + 1):
            if label[j, i] != obj:
                continue
            u = u0 + i * stride
            z = depth[j, i]
            x = (u - cx) / fx * z
            y = (v - cy) / fy * z
            n0, n1, n2 = normal[j, i, 0], normal[j, i, 1], normal[j, i, 2]
            if to_body:
                d0, d1, d2 = x - t[0], y - t[1], z - t[2]
                for c in range(3):
                    pts[m, c] = fma(d2, R[2, c], fma(d1, R[1, c], d0 * R[0, c]))
                    nrm[m, c] = fma(n2, R[2, c], fma(n1, R[1, c], n0 * R[0, c]))
            else:
                pts[m, 0], pts[m, 1], pts[m, 2] = x, y, z
                nrm[m, 0], nrm[m, 1], nrm[m, 2] = n0, n1, n2
            m += 1
    return pts, nrm


_NO_POSE = (np.eye(3), np.zeros(3))
"""The ``R``, ``t`` :func:`_cell_points` ignores for camera-frame points."""


def render_surfaces(
    intrinsics: Intrinsics,
    shapes: list,
    poses: list,
    rect: tuple[int, int, int, int],
    stride: int,
) -> SurfaceRender:
    """Render parts into one z-buffer over the image rectangle ``rect = (u0, v0, u1, v1)`` (end-exclusive) at
    ``stride`` px. ``shapes[k]``: ``("box", center (3,), half (3,))`` or ``("mesh", vertices (V, 3), faces (F, 3))``
    in the body frame; ``poses[k]``: ``(R (3, 3), t (3,))`` body → camera, or None to leave the part out."""
    u0, v0, u1, v1 = (int(x) for x in rect)
    s = max(int(stride), 1)
    nu = max((u1 - u0 + s - 1) // s, 0)
    nv = max((v1 - v0 + s - 1) // s, 0)
    zbuf = np.full((nv, nu), np.inf)
    label = np.full((nv, nu), -1, np.int32)
    normal = np.zeros((nv, nu, 3))
    if nu and nv:
        fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
        for k, (shape, pose) in enumerate(zip(shapes, poses, strict=True)):
            if pose is None:
                continue
            R = np.ascontiguousarray(pose[0], np.float64)
            t = np.ascontiguousarray(pose[1], np.float64)
            if shape[0] == "box":
                _render_box(zbuf, label, normal, u0, v0, s, fx, fy, cx, cy, R, t,
                            np.asarray(shape[1], np.float64), np.asarray(shape[2], np.float64), k, 0, 0)
            else:
                _render_mesh(zbuf, label, normal, u0, v0, s, fx, fy, cx, cy, R, t, shape[1], shape[2], k, 0, 0)
    return SurfaceRender(u0, v0, s, zbuf, label, normal)
