"""Silhouette (colour-region) residuals for the dense-depth refinement: the part's rendered outline should lie on the
edge of its colour blob.

Depth alone leaves a part seen through one face free to turn about that face's normal and to slide along it (the
point-to-plane residuals of a plane do not change); the Tikhonov prior then keeps whatever the filter proposed.
A cube held in a hand shows little more than one face, so its yaw drifts. ICG/M3T pair the depth modality with a
region modality for this reason; this is a simple form of it that uses the binary colour blob the detector
already gives (no colour histograms):

* **Contour points**, per part and frame: pixels of the part's rendered silhouette (the refinement's strided
  z-buffer, :mod:`tracker.refine.surface_render`) with a 4-neighbour that shows nothing or something farther away
  (an outline against the background, not against a part in front). Their surface points are kept in the body
  frame, like the depth model points.
* **Signed distance** of the blob: ``D(u) = dist_to_blob(u) − dist_to_background(u)`` (pixels, cv2 distance
  transforms on a crop around the part), with its image gradient ``∇D`` (unit, outward).
* **Residual** of contour point ``x = R p + t``: ``r = D(π(x)) + s/2`` pixels (a rendered outline pixel lies
  inside the outline by half the render's stride ``s``; the refiner renders outlines at s = 1); Jacobian
  ``∇D(π(x))ᵀ ∂π/∂x ∂x/∂ξ`` for the twist ``ξ = (ω, v)`` about the part's centre ``c``
  (``∂x/∂ω = −[x − c]×``, ``∂x/∂v = I``). Huber-weighted with scale ``sigma_px``; pairs are dropped where the
  measured depth lies more than ``occlusion_m`` in front of the point (a hand or a part hides the outline there,
  the blob's edge there is the occluder's) or where ``|r|`` exceeds ``max_px`` (no edge nearby to match).

Camera frame, metres, pixels, radians.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numba as nb
import numpy as np

from tracker.geometry.camera import Intrinsics
from tracker.refine.normal_equations import add_huber, twist_row
from tracker.refine.surface_render import (
    SurfaceRender,
    _box_bounds,
    _box_corners_px,
    _box_origin,
    _box_ray,
    _clip_window,
    _render_box,
    _render_mesh,
)


@dataclass(frozen=True)
class RegionSettings:
    """Parameters of the silhouette term."""

    sigma_px: float = 1.5
    """Scale (px) of the silhouette residuals (the blob edge's uncertainty)."""
    huber_k: float = 1.345
    """Huber threshold in units of ``sigma_px``."""
    max_px: float = 12.0
    """Contour points farther than this from the blob edge (px) are not paired."""
    occlusion_m: float = 0.015
    """A measurement this much in front of a contour point hides the outline there."""
    depth_agree_m: float = 0.0
    """A contour point outside the blob (by more than a pixel) whose measured depth is within this of its own (the
    depth shows the part there: the colour blob left out a shaded face) is not paired; 0 = off."""
    normal_cos: float = 0.0
    """A contour point is paired only where the blob's edge faces the same way as the rendered outline there: the
    cosine between the blob's outward gradient and the outward normal of the part's own rendered silhouette (at the
    start pose) must reach this. The nearest blob edge of a point on a shaded face the blob left out (a cube's side
    seen at a grazing angle, darker than its colour) is usually another edge of the blob, at right angles to the
    outline there; paired, it turned a cube under another by 10° on tuning seed 4 of guess-1 (session 18). 0 = off."""
    lines: float = 0.0
    """Correspondence lines (ICG/M3T's region modality), tolerance in px (0 = off): each contour point's blob edge is
    also searched along the outward normal of the part's own rendered silhouette there (:func:`_line_edge`; no
    crossing within ``max_px``: not paired); where the residual that edge gives differs from the signed distance's
    (the nearest edge's) by more than this, the nearest edge is another one (e.g. at right angles to the outline) and
    the point is paired along its normal; otherwise by the signed distance (exact at the true pose, where the line's
    crossing of a pixel staircase is not). Needs the own silhouette (:meth:`RegionTerm.set_own_silhouette`)."""
    weight: float = 1.0
    """Multiplier of the term's information against the depth term's."""
    max_points: int = 200
    """Contour points used per part (evenly thinned)."""


@nb.njit(cache=True)
def _outline_pixels(label: np.ndarray, z: np.ndarray, obj: int) -> tuple[np.ndarray, np.ndarray]:
    """Grid indices (rows, columns) of part ``obj``'s pixels with a 4-neighbour that is empty or farther away."""
    nv, nu = label.shape
    return _outline_window_pixels(label, z, obj, 0, 0, nu, nv)  # the window is the whole grid


def contour_points(render: SurfaceRender, obj: int, intrinsics: Intrinsics) -> np.ndarray:
    """Camera-frame surface points (C, 3) on part ``obj``'s outline in ``render`` (pixels of the part with a
    4-neighbour that is empty or farther away; the image border does not count as an outline)."""
    jj, ii = _outline_pixels(render.label, render.depth, obj)
    d = render.depth[jj, ii].astype(np.float64)
    u = render.u0 + ii * render.stride
    v = render.v0 + jj * render.stride
    return np.stack([(u - intrinsics.cx) / intrinsics.fx * d, (v - intrinsics.cy) / intrinsics.fy * d, d], axis=1)


@nb.njit(cache=True)
def _outline_window_pixels(label, z, obj, wi0, wj0, nu, nv):
    """:func:`_outline_pixels` of a window of a grid: ``label``, ``z`` hold the grid cells ``(wj0 + j, wi0 + i)`` of a
    grid of ``nv`` × ``nu`` cells; rows and columns returned in grid cells. A neighbour outside the grid does not make
    an outline (as there); one outside the window but inside the grid counts as empty (the caller's window holds
    every neighbour of the part's pixels, so this does not arise)."""
    mv, mu = label.shape
    rows = np.empty(mv * mu, np.int64)
    cols = np.empty(mv * mu, np.int64)
    n = 0
    for j in range(mv):
        for i in range(mu):
            if label[j, i] != obj:
                continue
            edge = False
            for k in range(4):
                jj = j + (1 if k == 0 else -1 if k == 1 else 0)
                ii = i + (1 if k == 2 else -1 if k == 3 else 0)
                if jj + wj0 < 0 or jj + wj0 >= nv or ii + wi0 < 0 or ii + wi0 >= nu:
                    continue  # the image border is not an outline
                if jj < 0 or jj >= mv or ii < 0 or ii >= mu:
                    edge = True
                    break
                lab = label[jj, ii]
                if lab != obj and (lab < 0 or z[jj, ii] > z[j, i]):
                    edge = True
                    break
            if edge:
                rows[n] = j + wj0
                cols[n] = i + wi0
                n += 1
    return rows[:n], cols[:n]


@nb.njit(cache=True)
def _own_window(kind, R, t, center, half, verts, u0, v0, nu, nv, fx, fy, cx, cy):
    """Grid cells ``(i0, i1, j0, j1)`` (inclusive, stride 1, grid origin ``(u0, v0)``, ``nu`` × ``nv`` cells) that hold
    every pixel a part at ``(R, t)`` can cover and their 4-neighbours: its projected corners' (a box) or vertices'
    (a mesh) rectangle widened by 2 cells, within the grid (all of it when a box corner lies near the camera plane).
    Empty (``i0 > i1``) when nothing of the part can be drawn."""
    umin, umax, vmin, vmax = np.inf, -np.inf, np.inf, -np.inf
    if kind == 0:
        umin, umax, vmin, vmax, near = _box_bounds(R, t, center, half, fx, fy, cx, cy)
        if near:
            return 0, nu - 1, 0, nv - 1
    else:  # a mesh draws only triangles whose three vertices lie beyond 1 mm
        for a in range(verts.shape[0]):
            x = R[0, 0] * verts[a, 0] + R[0, 1] * verts[a, 1] + R[0, 2] * verts[a, 2] + t[0]
            y = R[1, 0] * verts[a, 0] + R[1, 1] * verts[a, 1] + R[1, 2] * verts[a, 2] + t[1]
            z = R[2, 0] * verts[a, 0] + R[2, 1] * verts[a, 1] + R[2, 2] * verts[a, 2] + t[2]
            if z < 1e-3:
                continue
            umin, umax = min(umin, fx * x / z + cx), max(umax, fx * x / z + cx)
            vmin, vmax = min(vmin, fy * y / z + cy), max(vmax, fy * y / z + cy)
    if not (umin <= umax and vmin <= vmax and np.isfinite(umin) and np.isfinite(umax) and np.isfinite(vmin)
            and np.isfinite(vmax)):
        return 0, -1, 0, -1
    return _clip_window(umin, umax, vmin, vmax, u0, v0, nu, nv)


_BOX_EDGES = np.array([[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 4], [1, 5], [2, 6], [3, 7]],
                      np.int64)
"""Corner pairs of a box's 12 edges, corners numbered as the loops over (±x, ±y, ±z) visit them (z fastest)."""
_SURE_PX = 1e-4
"""A pixel centre this far (px) or farther from a box's projected outline is inside or outside it for sure: the ray
cast's rounding moves the outline by about 1e-12 px."""


@nb.njit(cache=True)
def _box_row_span(cu, cv, v, lo_v, hi_v):
    """The u-extent ``(lo, hi)`` (pixels) of a box's projected outline (corners ``cu``, ``cv``) between the rows
    ``v + lo_v`` and ``v + hi_v``: its corners in that band and where its edges cross the band's two rows
    (``(inf, −inf)`` when it has nothing there)."""
    lo, hi = np.inf, -np.inf
    for c in range(8):
        if v + lo_v <= cv[c] <= v + hi_v:
            lo, hi = min(lo, cu[c]), max(hi, cu[c])
    for e in range(12):  # the outline is made of projected edges of the box
        p, q = _BOX_EDGES[e, 0], _BOX_EDGES[e, 1]
        if cv[p] == cv[q]:
            continue
        for row in (v + lo_v, v + hi_v):
            if (cv[p] - row) * (cv[q] - row) <= 0.0:
                x = cu[p] + (row - cv[p]) * (cu[q] - cu[p]) / (cv[q] - cv[p])
                lo, hi = min(lo, x), max(hi, x)
    return lo, hi


@nb.njit(cache=True)
def _box_outline(kinds, Rs, ts, centers, halves, verts, faces, voff, foff, obj, R, t, rect, fx, fy, cx, cy):
    """Outline pixels of box ``obj`` at ``(R, t)`` among the drawn parts, exactly as the full render over ``rect``
    (stride 1) and :func:`_outline_pixels` find them; ``None`` when a corner of the box lies near the camera plane
    (the caller renders everything then).

    A box in front of the camera covers the cells inside its projected outline (the convex hull of its projected
    corners, whose sides are projected edges): a cell farther than ``_SURE_PX`` from that outline is inside or
    outside for sure (the ray cast's rounding is many orders of magnitude smaller), and only the cells closer to it
    are ray-cast (:func:`~tracker.refine.surface_render._box_ray`, the render's own arithmetic), as are cells that
    another part also covers (which one is in front) and outline cells next to another part. The other parts are
    rendered as usual over the box's window (its projected rectangle and 2 cells around it). Returns the outline
    cells' grid rows and columns (row-major, as :func:`_outline_pixels` lists them) and the box's origin for
    :func:`_thinned_points`."""
    u0, v0, u1, v1 = rect[0], rect[1], rect[2], rect[3]
    nu = max(u1 - u0, 0)
    nv = max(v1 - v0, 0)
    center, half = centers[obj], halves[obj]
    cu, cv, near = _box_corners_px(R, t, center, half, fx, fy, cx, cy)
    if near:
        return None
    umin, umax, vmin, vmax = cu.min(), cu.max(), cv.min(), cv.max()
    o = _box_origin(R, t, center)
    empty = np.empty(0, np.int64)
    wi0, wi1, wj0, wj1 = _clip_window(umin, umax, vmin, vmax, u0, v0, nu, nv)
    if wi0 > wi1:
        return empty, empty, o
    mu, mv = wi1 - wi0 + 1, wj1 - wj0 + 1
    # the other parts, as the render draws them (index order, nearest kept, the first on a tie)
    zo = np.full((mv, mu), np.inf)
    lo = np.full((mv, mu), -1, np.int32)
    no_normal = np.empty((0, 0, 3))
    for k in range(kinds.shape[0]):
        if kinds[k] < 0 or k == obj:
            continue
        if kinds[k] == 0:
            _render_box(zo, lo, no_normal, u0, v0, 1, fx, fy, cx, cy, Rs[k], ts[k], centers[k], halves[k], k, wi0, wj0)
        else:
            _render_mesh(zo, lo, no_normal, u0, v0, 1, fx, fy, cx, cy, Rs[k], ts[k], verts[voff[k]:voff[k + 1]],
                         faces[foff[k]:foff[k + 1]], k, wi0, wj0)
    others = False
    for jr in range(mv):
        for ir in range(mu):
            if lo[jr, ir] >= 0:
                others = True
    sure = _SURE_PX
    own = np.zeros((mv, mu), np.uint8)
    for j in range(wj0, wj1 + 1):
        v = float(v0 + j)
        if v < vmin - sure or v > vmax + sure:
            continue  # the row passes above or below the box
        yv = (v - cy) / fy
        jr = j - wj0
        if v < vmin + sure or v > vmax - sure:  # the row grazes a corner or an edge: cast where it could hit
            a, b = _box_row_span(cu, cv, v, -sure, sure)
            for i in range(max(int(np.floor(a - u0)) - 1, wi0), min(int(np.ceil(b - u0)) + 1, wi1) + 1):
                if _box_ray(o, R, half, (u0 + i - cx) / fx, yv)[0] < np.inf:
                    own[jr, i - wi0] = 1
            continue
        a, b = _box_row_span(cu, cv, v, 0.0, 0.0)
        for i in range(max(int(np.floor(a - u0 - sure)), wi0), min(int(np.ceil(b - u0 + sure)), wi1) + 1):
            u = float(u0 + i)
            if a + sure < u < b - sure:
                own[jr, i - wi0] = 1
            elif a - sure <= u <= b + sure and _box_ray(o, R, half, (u - cx) / fx, yv)[0] < np.inf:
                own[jr, i - wi0] = 1
    if others:  # where another part covers a cell of the box too, the nearer keeps it (the lower index on a tie)
        for jr in range(mv):
            yv = (v0 + wj0 + jr - cy) / fy
            for ir in range(mu):
                if own[jr, ir] == 1 and lo[jr, ir] >= 0:
                    z = _box_ray(o, R, half, (u0 + wi0 + ir - cx) / fx, yv)[0]
                    if not (z < zo[jr, ir] or (z == zo[jr, ir] and obj < lo[jr, ir])):
                        own[jr, ir] = 0
    # outline cells: a 4-neighbour (inside the grid) that shows nothing or a farther part
    rows = np.empty(mv * mu, np.int64)
    cols = np.empty(mv * mu, np.int64)
    n = 0
    for jr in range(mv):
        for ir in range(mu):
            if own[jr, ir] == 0:
                continue
            if (0 < jr < mv - 1 and 0 < ir < mu - 1 and own[jr - 1, ir] == 1 and own[jr + 1, ir] == 1
                    and own[jr, ir - 1] == 1 and own[jr, ir + 1] == 1):
                continue  # all four neighbours are the box's own
            edge = False
            z = np.nan
            for k in range(4):
                jj = jr + (1 if k == 0 else -1 if k == 1 else 0)
                ii = ir + (1 if k == 2 else -1 if k == 3 else 0)
                if jj + wj0 < 0 or jj + wj0 >= nv or ii + wi0 < 0 or ii + wi0 >= nu:
                    continue  # the image border is not an outline
                if jj < 0 or jj >= mv or ii < 0 or ii >= mu:
                    edge = True  # beyond the window: nothing there (the window holds the box and a margin)
                    break
                if own[jj, ii] == 1:
                    continue
                if lo[jj, ii] < 0:
                    edge = True
                    break
                if z != z:
                    z = _box_ray(o, R, half, (u0 + wi0 + ir - cx) / fx, (v0 + wj0 + jr - cy) / fy)[0]
                if zo[jj, ii] > z:
                    edge = True
                    break
            if edge:
                rows[n] = jr + wj0
                cols[n] = ir + wi0
                n += 1
    return rows[:n], cols[:n], o


@nb.njit(cache=True)
def _thin_indices(n: int, max_points: int) -> np.ndarray:
    """Indices of ``n`` outline cells evenly thinned to at most ``max_points``, as
    ``np.linspace(0, n − 1, max_points).round()`` picks them (all of them when there are no more)."""
    if n <= max_points:
        return np.arange(n)
    pick = np.empty(max_points, np.int64)
    step = (n - 1) / (max_points - 1) if max_points > 1 else 0.0
    for a in range(max_points):
        pick[a] = n - 1 if a == max_points - 1 and max_points > 1 else int(np.rint(a * step))
    return pick


@nb.njit(cache=True)
def _thinned_points(rows, cols, o, R, t, half, u0, v0, fx, fy, cx, cy, max_points):
    """Body-frame points of a box's outline cells (grid rows, columns; the box's ray cast there, ``o`` from
    :func:`~tracker.refine.surface_render._box_origin`), evenly thinned as :func:`_scene_outline` does."""
    pick = _thin_indices(rows.shape[0], max_points)
    out = np.empty((pick.shape[0], 3))
    for a in range(pick.shape[0]):
        j = pick[a]
        d = _box_ray(o, R, half, (u0 + cols[j] - cx) / fx, (v0 + rows[j] - cy) / fy)[0]
        p0 = (u0 + cols[j] - cx) / fx * d - t[0]
        p1 = (v0 + rows[j] - cy) / fy * d - t[1]
        p2 = d - t[2]
        for b in range(3):
            out[a, b] = p0 * R[0, b] + p1 * R[1, b] + p2 * R[2, b]
    return out


@nb.njit(cache=True)
def _scene_outline(kinds, Rs, ts, centers, halves, verts, faces, voff, foff, obj, R, t, rect, fx, fy, cx, cy,
                   max_points):
    """Body-frame outline points of part ``obj`` at pose ``(R, t)``, every other drawn part at ``(Rs[k], ts[k])``:
    the full-resolution render over ``rect = (u0, v0, u1, v1)`` (:func:`~tracker.refine.surface_render.render_surfaces`
    at stride 1), its outline pixels (:func:`_outline_pixels`), their surface points, evenly thinned to at most
    ``max_points`` (as ``np.linspace(0, C − 1, max_points).round()`` picks them). The numba form of
    :func:`body_outline` of such a render; ``kinds[k]``: 0 box (``centers``, ``halves``), 1 mesh (vertices
    ``verts[voff[k]:voff[k+1]]``, faces ``faces[foff[k]:foff[k+1]]`` indexing them), −1 not drawn. Only the window of
    the rectangle around the part itself is rendered (:func:`_own_window`; the outline depends on nothing else), with
    the same arithmetic per pixel: the points are those of the whole rectangle's render."""
    u0, v0, u1, v1 = rect[0], rect[1], rect[2], rect[3]
    if kinds[obj] == 0:
        found = _box_outline(kinds, Rs, ts, centers, halves, verts, faces, voff, foff, obj, R, t, rect, fx, fy, cx, cy)
        if found is not None:
            brows, bcols, o = found
            return _thinned_points(brows, bcols, o, R, t, halves[obj], u0, v0, fx, fy, cx, cy, max_points)
    nu = max(u1 - u0, 0)
    nv = max(v1 - v0, 0)
    wi0, wi1, wj0, wj1 = 0, -1, 0, -1
    if nu > 0 and nv > 0 and kinds[obj] >= 0:
        wi0, wi1, wj0, wj1 = _own_window(kinds[obj], R, t, centers[obj], halves[obj], verts[voff[obj]:voff[obj + 1]],
                                         u0, v0, nu, nv, fx, fy, cx, cy)
    mu = max(wi1 - wi0 + 1, 0)
    mv = max(wj1 - wj0 + 1, 0)
    zbuf = np.full((mv, mu), np.inf)
    label = np.full((mv, mu), -1, np.int32)
    normal = np.empty((0, 0, 3))  # not needed: not written
    if mu > 0 and mv > 0:
        for k in range(kinds.shape[0]):
            if kinds[k] < 0:
                continue
            Rk = R if k == obj else Rs[k]
            tk = t if k == obj else ts[k]
            if kinds[k] == 0:
                _render_box(zbuf, label, normal, u0, v0, 1, fx, fy, cx, cy, Rk, tk, centers[k], halves[k], k, wi0, wj0)
            else:
                _render_mesh(zbuf, label, normal, u0, v0, 1, fx, fy, cx, cy, Rk, tk, verts[voff[k]:voff[k + 1]],
                             faces[foff[k]:foff[k + 1]], k, wi0, wj0)
    rows, cols = _outline_window_pixels(label, zbuf, obj, wi0, wj0, nu, nv)
    pick = _thin_indices(rows.shape[0], max_points)
    out = np.empty((pick.shape[0], 3))
    for a in range(pick.shape[0]):
        j = pick[a]
        d = zbuf[rows[j] - wj0, cols[j] - wi0]
        p0 = (u0 + cols[j] - cx) / fx * d - t[0]
        p1 = (v0 + rows[j] - cy) / fy * d - t[1]
        p2 = d - t[2]
        for b in range(3):
            out[a, b] = p0 * R[0, b] + p1 * R[1, b] + p2 * R[2, b]
    return out


@dataclass
class OutlineScene:
    """Every part as :func:`_scene_outline` draws it, for the outline of part ``obj`` over ``rect``: the numba path of
    the refinement's silhouette term (:func:`tracker.refine.dense_depth.refine_pose`) re-renders the outline
    from this inside its Gauss-Newton loop. Arrays as :func:`_scene_outline` takes them; ``Rs``, ``ts`` the other
    parts' poses (body → camera)."""

    kinds: np.ndarray
    Rs: np.ndarray
    ts: np.ndarray
    centers: np.ndarray
    halves: np.ndarray
    verts: np.ndarray
    faces: np.ndarray
    voff: np.ndarray
    foff: np.ndarray
    obj: int
    rect: np.ndarray
    max_points: int

    @classmethod
    def of(cls, shapes: list, poses: list, obj: int, rect: tuple[int, int, int, int], max_points: int,
           packed: tuple | None = None) -> OutlineScene:
        """From :func:`~tracker.refine.surface_render.render_surfaces`' ``shapes`` and ``poses`` (None: not drawn);
        ``packed``: :func:`pack_shapes` of ``shapes`` when already made."""
        kinds, centers, halves, verts, faces, voff, foff = packed if packed is not None else pack_shapes(shapes)
        k = len(shapes)
        kinds = kinds.copy()
        Rs = np.zeros((k, 3, 3))
        ts = np.zeros((k, 3))
        for i, pose in enumerate(poses):
            if pose is None:
                kinds[i] = -1
            else:
                Rs[i], ts[i] = pose[0], pose[1]
        return cls(kinds, Rs, ts, centers, halves, verts, faces, voff, foff, int(obj),
                   np.asarray(rect, np.int64).reshape(4), int(max_points))

    def outline_at(self, R: np.ndarray, t: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
        """Body-frame outline points (C, 3) of part ``obj`` at ``(R, t)`` (the others where they are)."""
        return _scene_outline(self.kinds, self.Rs, self.ts, self.centers, self.halves, self.verts, self.faces,
                              self.voff, self.foff, self.obj, np.ascontiguousarray(R, np.float64),
                              np.ascontiguousarray(t, np.float64), self.rect, intrinsics.fx, intrinsics.fy,
                              intrinsics.cx, intrinsics.cy, self.max_points)


def pack_shapes(shapes: list) -> tuple:
    """The parts of :func:`~tracker.refine.surface_render.render_surfaces`' ``shapes`` as flat arrays for
    :func:`_scene_outline`: kinds (K,), box centres and half extents (K, 3), the meshes' vertices and faces stacked,
    with per-part offsets (K + 1,) into each."""
    k = len(shapes)
    kinds = np.zeros(k, np.int64)
    centers = np.zeros((k, 3))
    halves = np.zeros((k, 3))
    verts, faces = [np.zeros((0, 3))], [np.zeros((0, 3), np.int64)]
    voff = np.zeros(k + 1, np.int64)
    foff = np.zeros(k + 1, np.int64)
    for i, shape in enumerate(shapes):
        nvert = nface = 0
        if shape[0] == "box":
            centers[i], halves[i] = shape[1], shape[2]
        else:
            kinds[i] = 1
            verts.append(np.asarray(shape[1], np.float64))
            faces.append(np.asarray(shape[2], np.int64))
            nvert, nface = verts[-1].shape[0], faces[-1].shape[0]
        voff[i + 1] = voff[i] + nvert
        foff[i + 1] = foff[i] + nface
    return (kinds, centers, halves, np.ascontiguousarray(np.concatenate(verts)),
            np.ascontiguousarray(np.concatenate(faces)), voff, foff)


@nb.njit(cache=True)
def _accumulate(pts, R, t, c, sd, gu, gv, u0, v0, depth, fx, fy, cx, cy, inset, occlusion, agree, max_px, sigma,
                huber_k, weight, ogu, ogv, min_cos, lines=0.0):
    """Normal equations ``H`` (6, 6), ``g`` (6) of the silhouette residuals and the number of paired points (see
    :meth:`RegionTerm.normal_equations`). ``ogu``, ``ogv``: the outward normal field of the part's own rendered
    silhouette on the grid of ``sd`` (empty: no normal test and no lines), ``min_cos``:
    :attr:`RegionSettings.normal_cos`; ``lines``: :attr:`RegionSettings.lines` (each point's blob edge is searched
    along its own outline normal, :func:`_line_edge`, in place of the signed distance's nearest edge)."""
    H = np.zeros((6, 6))
    g = np.zeros(6)
    h, w = sd.shape
    hh, ww = depth.shape
    J = np.empty(6)
    n = 0
    for k in range(pts.shape[0]):
        x0 = R[0, 0] * pts[k, 0] + R[0, 1] * pts[k, 1] + R[0, 2] * pts[k, 2] + t[0]
        x1 = R[1, 0] * pts[k, 0] + R[1, 1] * pts[k, 1] + R[1, 2] * pts[k, 2] + t[1]
        x2 = R[2, 0] * pts[k, 0] + R[2, 1] * pts[k, 1] + R[2, 2] * pts[k, 2] + t[2]
        if x2 <= 1e-3:
            continue
        u = fx * x0 / x2 + cx
        v = fy * x1 / x2 + cy
        fu = u - u0
        fv = v - v0
        if not (fu >= 0.0 and fu <= w - 1 and fv >= 0.0 and fv <= h - 1):
            continue
        iu = int(np.floor(u + 0.5))
        iv = int(np.floor(v + 0.5))
        meas = np.nan
        if 0 <= iu < ww and 0 <= iv < hh:
            meas = depth[iv, iu]
            if meas > 0.0 and np.isfinite(meas) and meas < x2 - occlusion:
                continue  # a hand or a part in front hides the outline here
        i0 = min(int(np.floor(fu)), w - 2)
        j0 = min(int(np.floor(fv)), h - 2)
        a = fu - i0
        b = fv - j0
        w00 = (1 - a) * (1 - b)
        w01 = a * (1 - b)
        w10 = (1 - a) * b
        w11 = a * b
        r = w00 * sd[j0, i0] + w01 * sd[j0, i0 + 1] + w10 * sd[j0 + 1, i0] + w11 * sd[j0 + 1, i0 + 1] + inset
        du = w00 * gu[j0, i0] + w01 * gu[j0, i0 + 1] + w10 * gu[j0 + 1, i0] + w11 * gu[j0 + 1, i0 + 1]
        dv = w00 * gv[j0, i0] + w01 * gv[j0, i0 + 1] + w10 * gv[j0 + 1, i0] + w11 * gv[j0 + 1, i0 + 1]
        if agree > 0.0 and r > inset + 1.0 and meas > 0.0 and abs(meas - x2) < agree:
            continue  # outside the blob, but the depth shows the part's surface here: the blob missed a shaded face
        if lines > 0.0:
            ok, r, du, dv = _line_pair(sd, ogu, ogv, depth, fu, fv, u, v, x2, r, du, dv, inset, max_px, lines)
            if not ok:
                continue
        elif abs(r) > max_px or (du == 0.0 and dv == 0.0):
            continue
        elif min_cos > 0.0 and ogu.shape[0] == h and ogu.shape[1] == w:
            nu_, nv_ = _own_normal(ogu, ogv, fu, fv)
            nn = np.sqrt(nu_ * nu_ + nv_ * nv_) * np.sqrt(du * du + dv * dv)
            if nn > 0.0 and (nu_ * du + nv_ * dv) < min_cos * nn:
                continue  # the nearest blob edge faces another way than the outline here: not this edge's match
        # dr/dx = grad D . dpi/dx
        e0 = du * fx / x2
        e1 = dv * fy / x2
        e2 = -(du * fx * x0 + dv * fy * x1) / (x2 * x2)
        twist_row(J, x0, x1, x2, c, e0, e1, e2)
        add_huber(H, g, J, r, sigma, huber_k, weight)
        n += 1
    for p in range(6):
        for q in range(p):
            H[p, q] = H[q, p]
    return H, g, n


@nb.njit(cache=True, inline="always")
def _own_normal(ogu, ogv, fu, fv):
    """The own silhouette's normal field at its nearest cell to the sub-pixel position ``(fu, fv)`` (not unit)."""
    h, w = ogu.shape
    jn = min(max(int(np.floor(fv + 0.5)), 0), h - 1)
    inn = min(max(int(np.floor(fu + 0.5)), 0), w - 1)
    return ogu[jn, inn], ogv[jn, inn]


@nb.njit(cache=True, inline="always")
def _line_pair(sd, ogu, ogv, depth, fu, fv, u, v, x2, r, du, dv, inset, max_px, tol):
    """The correspondence-line pairing of one contour point (:attr:`RegionSettings.lines` = ``tol``): from its
    signed-distance residual ``r`` and gradient ``(du, dv)`` at grid position ``(fu, fv)`` (image ``(u, v)``, depth
    ``x2``), ``(ok, r, du, dv)`` of the pair to use — the signed distance's where its nearest edge faces the outline's
    own normal or gives the line's edge within ``tol``, else the line's (:func:`_line_edge`); ``ok`` False when
    there is no own normal, no edge along the line, or the paired edge is an occluder's (a measurement
    ``EDGE_OCCLUDER_M`` nearer than the point ``EDGE_BEYOND_PX`` beyond it, outside the blob)."""
    h, w = sd.shape
    if ogu.shape[0] != h or ogu.shape[1] != w:
        return False, r, du, dv  # no own normals: nothing to search along
    nu_, nv_ = _own_normal(ogu, ogv, fu, fv)
    nn = np.sqrt(nu_ * nu_ + nv_ * nv_)
    if nn == 0.0:
        return False, r, du, dv
    gn = np.sqrt(du * du + dv * dv)
    if not (abs(r) <= max_px and gn > 0.0 and nu_ * du + nv_ * dv >= LINE_SAME_COS * nn * gn):
        # the nearest edge does not face the outline's way: search the line
        s_edge = _line_edge(sd, fu, fv, nu_ / nn, nv_ / nn, max_px)
        if not np.isfinite(s_edge):
            return False, r, du, dv  # no edge of the blob facing this way along the line
        r_line = inset - s_edge
        if abs(r_line - r) > tol:  # the nearest edge is another than the line's: pair along the line
            r, du, dv = r_line, nu_ / nn, nv_ / nn
        elif abs(r) > max_px or gn == 0.0:
            return False, r, du, dv
    # the paired edge, and the pixel just beyond it outside the blob: a measurement in front of the point there makes
    # it an occluder's edge (a hand or a part in front cuts the blob), not the part's outline
    gn = np.sqrt(du * du + dv * dv)
    beyond = r - inset - EDGE_BEYOND_PX
    ju = int(np.floor(u - beyond * du / gn + 0.5))
    jv = int(np.floor(v - beyond * dv / gn + 0.5))
    hh, ww = depth.shape
    if 0 <= ju < ww and 0 <= jv < hh:
        em = depth[jv, ju]
        if em > 0.0 and np.isfinite(em) and em < x2 - EDGE_OCCLUDER_M:
            return False, r, du, dv
    return True, r, du, dv


EDGE_BEYOND_PX = 1.5
"""With the correspondence lines: how far (px) beyond a paired blob edge, outside the blob, the depth is read to
tell an occluder's edge from the part's outline (:func:`_accumulate`)."""
EDGE_OCCLUDER_M = 0.005
"""With the correspondence lines: a measurement this much (m) in front of a contour point just beyond its paired
blob edge makes that edge an occluder's: the pair is dropped."""
LINE_SAME_COS = 0.95
"""With the correspondence lines: a contour point whose nearest blob edge (the signed distance's gradient) is within
this cosine of its outline normal is paired by the signed distance without searching its line (the nearest edge is
the line's)."""
LINE_STEP_PX = 0.5
"""Sampling step (px) of the search along a correspondence line (:func:`_line_edge`)."""


@nb.njit(cache=True, inline="always")
def _bilinear(a, fu, fv):
    """``a`` at the sub-pixel position ``(fu, fv)`` (columns, rows; inside the grid)."""
    h, w = a.shape
    i0 = min(int(np.floor(fu)), w - 2)
    j0 = min(int(np.floor(fv)), h - 2)
    x = fu - i0
    y = fv - j0
    return ((1 - x) * (1 - y) * a[j0, i0] + x * (1 - y) * a[j0, i0 + 1] + (1 - x) * y * a[j0 + 1, i0]
            + x * y * a[j0 + 1, i0 + 1])


@nb.njit(cache=True)
def _line_edge(sd, fu, fv, nu, nv, max_px):
    """Position ``s`` (px) along the correspondence line ``(fu, fv) + s (nu, nv)`` (grid of ``sd``, unit outward
    normal ``(nu, nv)`` of the part's rendered outline there) of the nearest crossing of the blob's edge from inside
    (``sd`` < 0) to outside in the normal's direction, within ``|s|`` ≤ ``max_px``; ``inf`` when there is none.

    This is the correspondence-line search of ICG/M3T's region modality on a binary blob: an outline point is paired
    only with an edge that it would reach by moving along its own normal, never with an edge at right angles to it
    (the nearest edge of the signed distance, which a shaded face the blob left out offers). The crossing is placed
    by linear interpolation of ``sd`` between the two samples around it (``sd`` is a distance: linear across an
    edge)."""
    h, w = sd.shape
    step = LINE_STEP_PX
    n = int(np.floor(max_px / step))
    d0 = _bilinear(sd, fu, fv)
    # walk outward from s = 0 both ways at once; the first interval (nearest first) with a crossing wins
    prev_f, prev_b = d0, d0
    alive_f, alive_b = True, True
    for k in range(1, n + 1):
        for side in range(2):
            if (side == 0 and not alive_f) or (side == 1 and not alive_b):
                continue
            s = k * step if side == 0 else -k * step
            pu = fu + s * nu
            pv = fv + s * nv
            if not (pu >= 0.0 and pu <= w - 1 and pv >= 0.0 and pv <= h - 1):
                if side == 0:
                    alive_f = False
                else:
                    alive_b = False
                continue
            d = _bilinear(sd, pu, pv)
            if side == 0:  # interval [s − step, s]: inside at its start, outside at its end
                if prev_f < 0.0 <= d:
                    return s - step + step * (-prev_f) / (d - prev_f)
                prev_f = d
            else:  # interval [s, s + step]
                if d < 0.0 <= prev_b:
                    return s + step * (-d) / (prev_b - d)
                prev_b = d
    return np.inf


@nb.njit(cache=True)
def _squared_edt(crop, target_value):
    """Exact squared Euclidean distance (px²) from every pixel of ``crop`` to the nearest pixel whose value is
    ``target_value`` (0 at such pixels): a column pass, then per row the lower envelope of parabolas (Felzenszwalb
    and Huttenlocher), as OpenCV's ``distanceTransform(…, DIST_L2, DIST_MASK_PRECISE)`` computes it. Pixels with no
    target in the image get a value larger than any distance in it. (The column pass runs along rows for all columns
    at once: memory in order.)"""
    h, w = crop.shape
    big = float((h + w) * (h + w) + 1)
    f = np.empty((h, w))
    last = np.full(w, -1, np.int64)  # per column, the row of the last target pixel seen (rows visited in order)
    for y in range(h):
        for x in range(w):
            if (crop[y, x] != 0) == (target_value != 0):
                last[x] = y
                f[y, x] = 0.0
            elif last[x] >= 0:
                f[y, x] = float(y - last[x])
            else:
                f[y, x] = -1.0
    last[:] = -1
    for y in range(h - 1, -1, -1):
        for x in range(w):
            if f[y, x] == 0.0:
                last[x] = y
            elif last[x] >= 0 and (f[y, x] < 0.0 or last[x] - y < f[y, x]):
                f[y, x] = float(last[x] - y)
            f[y, x] = big if f[y, x] < 0.0 else f[y, x] * f[y, x]
    out = np.empty((h, w))
    v = np.empty(w, np.int64)
    z = np.empty(w + 1)
    for y in range(h):
        k = -1
        for q in range(w):
            if f[y, q] >= big:
                continue
            if k < 0:
                k = 0
                v[0] = q
                z[0] = -np.inf
                z[1] = np.inf
                continue
            fq = f[y, q] + q * q
            s = (fq - (f[y, v[k]] + v[k] * v[k])) / (2.0 * (q - v[k]))
            while s <= z[k]:
                k -= 1
                s = (fq - (f[y, v[k]] + v[k] * v[k])) / (2.0 * (q - v[k]))
            k += 1
            v[k] = q
            z[k] = s
            z[k + 1] = np.inf
        if k < 0:
            for q in range(w):
                out[y, q] = big
            continue
        k = 0
        for q in range(w):
            while z[k + 1] < q:
                k += 1
            out[y, q] = (q - v[k]) * (q - v[k]) + f[y, v[k]]
    return out


BAND_FAR = 1e6
"""Value of the signed distance beyond the band of :func:`_signed_distance` (px): farther than any pairing reaches."""


@nb.njit(cache=True)
def _signed_distance(crop, band=0):
    """Signed distance (px, float64) of a binary crop's blob and its gradient (``gu`` along columns, ``gv`` along
    rows; central differences inside, one-sided at the border, as ``np.gradient``): ``0.5 − d_in`` inside the blob,
    ``d_out − 0.5`` outside, with the exact Euclidean distances taken in float32 as OpenCV returns them (the values of
    ``np.where(crop > 0, 0.5 − inside, outside − 0.5)`` over OpenCV's float32 distance images).

    ``band`` > 0: only the window of the blob's bounding box widened by ``band`` px gets these values (every blob
    pixel lies in it, so its outside distances are those of the whole crop); beyond it ``d`` is :data:`BAND_FAR`
    and the gradient 0. With ``band`` ≥ ``max_px`` + 4 the silhouette term pairs exactly the same points with the
    same values (a point whose bilinear neighbours or their gradient stencils reach beyond the window lies more than
    ``max_px`` + 1 from the blob, and the far values only make its residual larger: it is rejected either way)."""
    h, w = crop.shape
    # inside the blob only the distances to the background count, and the nearest background pixel of a blob pixel
    # lies within the blob's bounding box and the ring of background around it (a pixel beyond it has one on the
    # ring at most as far in each axis): that window's distance transform gives the same values there
    y0, y1, x0, x1 = h, -1, w, -1
    for y in range(h):
        for x in range(w):
            if crop[y, x] > 0:
                y0, y1, x0, x1 = min(y0, y), max(y1, y), min(x0, x), max(x1, x)
    ya, yb, xa, xb = max(y0 - 1, 0), min(y1 + 2, h), max(x0 - 1, 0), min(x1 + 2, w)
    inside = _squared_edt(crop[ya:yb, xa:xb], 0) if y1 >= 0 else np.zeros((0, 0))
    # the window that gets values: the whole crop, or the blob's box widened by the band
    wy0, wy1, wx0, wx1 = 0, h, 0, w
    if band > 0 and y1 >= 0:
        wy0, wy1, wx0, wx1 = max(y0 - band, 0), min(y1 + band + 1, h), max(x0 - band, 0), min(x1 + band + 1, w)
    outside = _squared_edt(crop[wy0:wy1, wx0:wx1], 1)
    half = np.float32(0.5)
    d = np.empty((h, w))
    gu = np.empty((h, w))
    gv = np.empty((h, w))
    if wy0 > 0 or wy1 < h or wx0 > 0 or wx1 < w:
        d[:, :] = BAND_FAR
        gu[:, :] = 0.0
        gv[:, :] = 0.0
    for y in range(wy0, wy1):
        for x in range(wx0, wx1):
            if crop[y, x] > 0:
                d[y, x] = half - np.float32(np.sqrt(inside[y - ya, x - xa]))
            else:
                d[y, x] = np.float32(np.sqrt(outside[y - wy0, x - wx0])) - half
    for y in range(wy0, wy1):
        for x in range(wx0, wx1):
            if x == 0:
                gu[y, x] = (d[y, 1] - d[y, 0]) / 1.0
            elif x == w - 1:
                gu[y, x] = (d[y, w - 1] - d[y, w - 2]) / 1.0
            else:
                gu[y, x] = (d[y, x + 1] - d[y, x - 1]) / 2.0
            if y == 0:
                gv[y, x] = (d[1, x] - d[0, x]) / 1.0
            elif y == h - 1:
                gv[y, x] = (d[h - 1, x] - d[h - 2, x]) / 1.0
            else:
                gv[y, x] = (d[y + 1, x] - d[y - 1, x]) / 2.0
    return d, gu, gv


@dataclass
class SignedDistance:
    """Signed distance (px) to a blob's edge over the crop whose top-left image pixel is ``(u0, v0)``: negative
    inside the blob; ``gu``, ``gv`` its image gradient."""

    u0: int
    v0: int
    d: np.ndarray
    gu: np.ndarray
    gv: np.ndarray

    @classmethod
    def of_outline(cls, outline: np.ndarray, rect: tuple[int, int, int, int], shape: tuple[int, int],
                   margin: int = 16, band: int = 0) -> SignedDistance | None:
        """Of the blob bounded by the polygon ``outline`` ((N, 2) image pixels, as the colour detector gives it, not
        eroded) over ``rect = (u0, v0, u1, v1)`` widened by ``margin`` px within an image of ``shape`` (h, w);
        ``band`` > 0: values only within that many px of the blob's box (:func:`_signed_distance`)."""
        pts = np.asarray(outline, np.float64).reshape(-1, 2)
        h, w = shape
        u0, v0 = max(rect[0] - margin, 0), max(rect[1] - margin, 0)
        u1, v1 = min(rect[2] + margin, w), min(rect[3] + margin, h)
        if pts.shape[0] < 3 or u0 >= u1 or v0 >= v1:
            return None
        crop = np.zeros((v1 - v0, u1 - u0), np.uint8)
        cv2.fillPoly(crop, [np.round(pts - [u0, v0]).astype(np.int32)], 1)
        return cls._of_crop(crop, u0, v0, band)

    @classmethod
    def _of_crop(cls, crop: np.ndarray, u0: int, v0: int, band: int = 0) -> SignedDistance | None:
        n_in = int(cv2.countNonZero(crop))  # the crop holds 0 and 1: its sum
        if n_in == 0 or n_in == crop.size:
            return None
        if min(crop.shape) < 2:
            return None  # no gradient across a one-pixel strip
        d, gu, gv = _signed_distance(np.ascontiguousarray(crop, np.uint8), int(band))
        return cls(u0, v0, d, gu, gv)


NORMAL_BLUR_PX = 2.0
"""Standard deviation (px) of the Gaussian that smooths the own silhouette before its gradient gives the outline's
normals (:meth:`RegionTerm.set_own_silhouette`)."""


@nb.njit(cache=True)
def _outward_normals(soft):
    """``(nu, nv)``: the negated gradient (per px, float64, H×W each) of the blurred silhouette ``soft`` (float32 H×W,
    both sides >= 2): central differences inside, one-sided at the borders — the values of ``-numpy.gradient``."""
    h, w = soft.shape
    nu = np.empty((h, w))
    nv = np.empty((h, w))
    for j in range(h):
        for i in range(w):
            if i == 0:
                du = np.float64(soft[j, 1]) - np.float64(soft[j, 0])
            elif i == w - 1:
                du = np.float64(soft[j, w - 1]) - np.float64(soft[j, w - 2])
            else:
                du = (np.float64(soft[j, i + 1]) - np.float64(soft[j, i - 1])) / 2.0
            if j == 0:
                dv = np.float64(soft[1, i]) - np.float64(soft[0, i])
            elif j == h - 1:
                dv = np.float64(soft[h - 1, i]) - np.float64(soft[h - 2, i])
            else:
                dv = (np.float64(soft[j + 1, i]) - np.float64(soft[j - 1, i])) / 2.0
            nu[j, i] = -du
            nv[j, i] = -dv
    return nu, nv


_NO_FIELD = np.zeros((0, 0))
"""An empty normal field: :func:`_accumulate` without the normal test."""


@dataclass
class RegionTerm:
    """The silhouette term of one part for one frame: contour points (body frame) and the blob's signed
    distance."""

    points: np.ndarray
    sdf: SignedDistance
    settings: RegionSettings
    inset: float = 0.0
    outline_at: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    """Optional: body-frame outline points at a pose ``(R, t)``; called whenever the pose has changed, so the outline
    pixels are the current pose's own (points carried over from the start pose drift off the outline by up to a pixel
    as the part turns, which biases the optimum)."""
    frame_depth: np.ndarray | None = None
    """Optional: the depth image to test what hides the outline on, in place of the one passed to
    :meth:`normal_equations` (which may have occluder pixels removed: a hand's pixels must still count as in front)."""
    pose: tuple[np.ndarray, np.ndarray] | None = None
    """The pose ``points`` were extracted at."""
    scene: OutlineScene | None = None
    """Optional: the outline as :attr:`outline_at` gives it, in numba form (the refinement then runs its whole
    Gauss-Newton loop in numba, :func:`tracker.refine.dense_depth.refine_pose`)."""
    own_normal: tuple[np.ndarray, np.ndarray] | None = None
    """Optional: the outward normal field ``(gu, gv)`` of the part's own rendered silhouette at the start pose, on the
    grid of :attr:`sdf` (:meth:`set_own_silhouette`), for :attr:`RegionSettings.normal_cos`."""

    def set_own_silhouette(self, own: np.ndarray) -> None:
        """Take the part's own visible silhouette at the start pose (bool, the shape of :attr:`sdf`'s grid) for the
        normal test or the correspondence lines; a silhouette that fills or misses the whole grid gives none.

        For the lines (:attr:`RegionSettings.lines` > 0) the outward normal field is the negated gradient of the
        silhouette blurred with a Gaussian of :data:`NORMAL_BLUR_PX` (the pixel mask's own distance transform gives
        only the directions 0°, 45° and 90° along a slanted edge's staircase, which a line would follow); for the
        normal test alone, the gradient of the silhouette's signed distance."""
        mask = np.ascontiguousarray(own, np.uint8)
        n_in = int(cv2.countNonZero(mask))
        if n_in == 0 or n_in == mask.size or min(mask.shape) < 2:
            self.own_normal = None
        elif self.settings.lines > 0.0:
            self.own_normal = _outward_normals(cv2.GaussianBlur(mask.astype(np.float32), (0, 0), NORMAL_BLUR_PX))
        else:
            f = SignedDistance._of_crop(mask, self.sdf.u0, self.sdf.v0)
            self.own_normal = None if f is None else (f.gu, f.gv)

    def normal_arrays(self) -> tuple[np.ndarray, np.ndarray, float, float]:
        """``(gu, gv, min_cos, lines)`` for :func:`_accumulate` (empty arrays and zeros when neither the normal
        test nor the correspondence lines are on)."""
        cfg = self.settings
        if self.own_normal is None or (cfg.normal_cos <= 0.0 and cfg.lines <= 0.0):
            return _NO_FIELD, _NO_FIELD, 0.0, 0.0
        return self.own_normal[0], self.own_normal[1], float(cfg.normal_cos), float(cfg.lines)

    def normal_equations(self, R: np.ndarray, t: np.ndarray, c: np.ndarray, depth: np.ndarray,
                         intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray, int]:
        """``H`` (6, 6), ``g`` (6) of the weighted silhouette residuals at pose ``(R, t)`` (twist about the
        camera-frame centre ``c``) and the number of paired contour points."""
        cfg = self.settings
        if self.outline_at is not None and not (
                self.pose is not None and np.array_equal(self.pose[0], R) and np.array_equal(self.pose[1], t)):
            pts = self.outline_at(R, t)
            self.pose = (np.array(R, np.float64), np.array(t, np.float64))
            if pts.shape[0] >= 8:
                self.points = pts
        f = self.sdf
        ogu, ogv, min_cos, lines = self.normal_arrays()
        return _accumulate(np.ascontiguousarray(self.points, np.float64), np.ascontiguousarray(R, np.float64),
                           np.ascontiguousarray(t, np.float64), np.ascontiguousarray(c, np.float64), f.d, f.gu, f.gv,
                           float(f.u0), float(f.v0), depth if self.frame_depth is None else self.frame_depth,
                           intrinsics.fx, intrinsics.fy, intrinsics.cx,
                           intrinsics.cy, float(self.inset), cfg.occlusion_m, cfg.depth_agree_m, cfg.max_px,
                           cfg.sigma_px, cfg.huber_k,
                           cfg.weight, ogu, ogv, min_cos, lines)


def body_outline(render: SurfaceRender, obj: int, R: np.ndarray, t: np.ndarray, intrinsics: Intrinsics,
                 max_points: int) -> np.ndarray:
    """Outline points of part ``obj`` in ``render`` (made at pose ``(R, t)``) in the body frame, evenly thinned to
    at most ``max_points``."""
    pts = contour_points(render, obj, intrinsics)
    if pts.shape[0] > max_points:
        pts = pts[np.linspace(0, pts.shape[0] - 1, max_points).round().astype(np.int64)]
    return (pts - t) @ R


def region_term(outline_at: Callable[[np.ndarray, np.ndarray], np.ndarray], R: np.ndarray, t: np.ndarray,
                outline: np.ndarray | None, intrinsics: Intrinsics, rect: tuple[int, int, int, int],
                settings: RegionSettings, stride: int = 1, frame_depth: np.ndarray | None = None) -> RegionTerm | None:
    """The silhouette term of a part at ``(R, t)`` against its colour blob's ``outline`` (polygon, (N, 2) image
    pixels), or None without a blob or a rendered outline. ``outline_at``: :attr:`RegionTerm.outline_at` (renders of
    stride ``stride``); ``frame_depth``: :attr:`RegionTerm.frame_depth`."""
    if outline is None:
        return None
    pts = outline_at(R, t)
    if pts.shape[0] < 8:
        return None
    # values only where a pairing can reach them (same pairs and residuals as over the whole crop)
    sdf = SignedDistance.of_outline(outline, rect, (intrinsics.height, intrinsics.width),
                                    band=int(np.ceil(settings.max_px)) + 4)
    if sdf is None:
        return None
    return RegionTerm(pts, sdf, settings, 0.5 * stride, outline_at,
                      None if frame_depth is None else np.ascontiguousarray(frame_depth, np.float32),
                      (np.array(R, np.float64), np.array(t, np.float64)))
