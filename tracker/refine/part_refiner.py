"""The refinement stage of the tracker: every visible part, every frame (spec ``depth-refinement.md``).

Once per frame all parts are rendered at their filter estimates into one z-buffer (so a pixel counts for at most
one part, the nearest); each part's visible surface points, with normals, become its model points for the frame,
and :func:`~tracker.refine.dense_depth.refine_pose` polishes the parts nearest first. A correction is accepted
when the refinement is healthy and the correction stays within bounds; the caller moves the part's particles by
it (:meth:`Correction.apply_to`). Camera frame, metres, radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from tracker.filter.motion_model import rotate_left
from tracker.geometry.camera import Intrinsics
from tracker.geometry.fma import rigid_point
from tracker.refine.dense_depth import RefineResult, RefineSettings, refine_pose
from tracker.refine.region_term import OutlineScene, RegionSettings, pack_shapes, region_term
from tracker.refine.surface_render import SurfaceRender, render_surfaces


@dataclass
class Correction:
    """Accepted refinement of one part: ``Rd``, ``td`` map the filter's pose onto the refined one
    (``R_ref = Rd R_pf``, ``t_ref = Rd t_pf + td``)."""

    R: np.ndarray
    t: np.ndarray
    Rd: np.ndarray
    td: np.ndarray
    result: RefineResult

    def apply_to(self, p: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Particles (positions (N, 3), rotations (N, 3, 3)) moved rigidly with the correction."""
        return p @ self.Rd.T + self.td, rotate_left(np.ascontiguousarray(self.Rd, np.float64),
                                                    np.asarray(R, np.float64))


def rotation_angle(Rd: np.ndarray) -> float:
    """Angle (rad) of a rotation matrix: ``arccos(clip((trace − 1) / 2, −1, 1))``, the trace summed as
    ``np.trace`` sums it and clipped on Python floats (the same value, without two numpy calls)."""
    c = ((float(Rd[0, 0]) + float(Rd[1, 1]) + float(Rd[2, 2])) - 1.0) / 2.0
    return float(np.arccos(min(max(c, -1.0), 1.0)))


class PartRefiner:
    """Dense-depth refinement of several parts at once (see module docstring).

    ``shapes[k]``: ``("box", center (3,), half (3,))`` or ``("mesh", vertices (V, 3), faces (F, 3))``, body frame;
    ``centers[k]``: the body-frame point a part's rotation update turns about; ``corners[k]``: (8, 3) body-frame
    corners of its bounding box (for the image region to render).
    """

    def __init__(self, intrinsics: Intrinsics, shapes: list, centers: list[np.ndarray], corners: list[np.ndarray],
                 settings: RefineSettings, stride: int = 2, max_translation: float = 0.03,
                 max_rotation: float = 0.35, region: RegionSettings | None = None,
                 short_settings: RefineSettings | None = None) -> None:
        self.intrinsics = intrinsics
        self.shapes = shapes
        self.centers = [np.asarray(c, np.float64) for c in centers]
        self.corners = [np.asarray(c, np.float64) for c in corners]
        self.settings = settings
        self.stride = int(stride)
        self.max_translation = float(max_translation)
        self.max_rotation = float(max_rotation)
        self.region = region  # silhouette term against the colour blob (None = depth only)
        self.short_settings = short_settings  # for the parts :meth:`refine` is told need less (fewer thresholds)
        self.last: list[RefineResult | None] = [None] * len(shapes)
        self._packed = pack_shapes(shapes)  # the shapes as the numba outline renderer takes them

    def _bounds(self, obj: int, pose: tuple) -> tuple[float, float, float, float] | None:
        """Image bounds ``(u_min, v_min, u_max, v_max)`` of part ``obj``'s box corners at ``pose``; None when a corner
        lies closer than 2 cm to the camera plane (:func:`_corner_bounds`)."""
        intr = self.intrinsics
        u0, v0, u1, v1, near = _corner_bounds(self.corners[obj], np.ascontiguousarray(pose[0], np.float64),
                                              np.ascontiguousarray(pose[1], np.float64), intr.fx, intr.fy, intr.cx,
                                              intr.cy)
        return None if near else (u0, v0, u1, v1)

    def _rect(self, poses: list, bounds: list | None = None) -> tuple[int, int, int, int] | None:
        """Pixel rectangle ``(u0, v0, u1, v1)`` (end exclusive, one pixel of margin, two at the far end) covering
        the parts with a pose; the whole image when one is too near the camera; None when none projects or it lies
        off the image. ``bounds``: :meth:`_bounds` of every part at ``poses`` when already computed."""
        intr = self.intrinsics
        lo0 = lo1 = np.inf
        hi0 = hi1 = -np.inf
        for obj, pose in enumerate(poses):
            if pose is None:
                continue
            b = self._bounds(obj, pose) if bounds is None else bounds[obj]
            if b is None:
                return (0, 0, intr.width, intr.height)
            if b[0] != b[0] or b[1] != b[1] or b[2] != b[2] or b[3] != b[3]:
                return None  # not a number: no rectangle
            lo0, lo1, hi0, hi1 = min(lo0, b[0]), min(lo1, b[1]), max(hi0, b[2]), max(hi1, b[3])
        if not (math.isfinite(lo0) and math.isfinite(lo1)):
            return None
        u0, v0 = max(math.floor(lo0) - 1, 0), max(math.floor(lo1) - 1, 0)
        u1, v1 = min(math.ceil(hi0) + 2, intr.width), min(math.ceil(hi1) + 2, intr.height)
        if u0 >= u1 or v0 >= v1:
            return None
        return (u0, v0, u1, v1)

    def refine_one(self, depth: np.ndarray, obj: int, R: np.ndarray, t: np.ndarray,
                   allowed: np.ndarray | None = None, outline: np.ndarray | None = None,
                   frame_depth: np.ndarray | None = None) -> RefineResult:
        """Refine part ``obj`` alone from the pose ``(R, t)`` (rendered without the other parts): used to try
        several starting poses when a part is re-acquired (:mod:`tracker.refine.recovery`)."""
        poses = [None] * len(self.shapes)
        poses[obj] = (np.asarray(R, np.float64), np.asarray(t, np.float64))
        rect = self._rect(poses)
        if rect is None:
            return RefineResult(poses[obj][0], poses[obj][1], False, 0, 0, 0.0, float("nan"), reason="off the image")
        render = render_surfaces(self.intrinsics, self.shapes, poses, rect, self.stride)
        R0, t0 = poses[obj]
        body, nbody = render.body_points_of(obj, self.intrinsics, R0, t0)
        region = self._region(poses, obj, outline, depth if frame_depth is None else frame_depth)
        return refine_pose(depth, self.intrinsics, body, nbody, R0, t0, self.centers[obj], self.settings, allowed,
                           region)

    def _region(self, poses: list, obj: int, outline: np.ndarray | None, frame_depth: np.ndarray,
                bounds: list | None = None, render: SurfaceRender | None = None):
        """Silhouette term of part ``obj`` (None without an outline or with the term off). Its outline is taken
        from a render at full resolution over the part's own rectangle (every part drawn, so that an outline
        against a part in front is not used): at the true pose the rendered and the detected blob then cover the
        same pixels and the residuals vanish exactly. ``bounds``: :meth:`_bounds` of the parts at ``poses`` when
        already computed; ``render``: the frame's strided render of the parts at ``poses`` (the own silhouette for the
        correspondence lines' normals is then sampled from it, not rendered again)."""
        if self.region is None or self.region.weight <= 0.0 or outline is None or poses[obj] is None:
            return None
        own = [None] * len(poses)
        own[obj] = poses[obj]
        rect = self._rect(own, bounds)
        if rect is None:
            return None
        R0, t0 = (np.asarray(a, np.float64) for a in poses[obj])
        cfg = self.region
        u0, v0, u1, v1 = rect
        pad = 8  # the part may move a few pixels while it is refined
        rect = (max(u0 - pad, 0), max(v0 - pad, 0), min(u1 + pad, self.intrinsics.width),
                min(v1 + pad, self.intrinsics.height))

        scene = OutlineScene.of(self.shapes, poses, obj, rect, cfg.max_points, self._packed)

        def outline_at(R: np.ndarray, t: np.ndarray) -> np.ndarray:
            return scene.outline_at(R, t, self.intrinsics)

        term = region_term(outline_at, R0, t0, outline, self.intrinsics, rect, cfg, 1, frame_depth)
        if term is not None:
            term.scene = scene
            if cfg.normal_cos > 0.0 or cfg.lines > 0.0:  # own normals: the visible silhouette
                h, w = term.sdf.d.shape
                u0, v0 = term.sdf.u0, term.sdf.v0
                if render is not None and cfg.lines > 0.0:  # smoothed anyway: the strided render's nearest sample
                    term.set_own_silhouette(_sampled_silhouette(render, obj, u0, v0, w, h))
                else:
                    own = render_surfaces(self.intrinsics, self.shapes, poses, (u0, v0, u0 + w, v0 + h), 1)
                    term.set_own_silhouette(own.label == obj)
        return term

    def correction(self, R0: np.ndarray, t0: np.ndarray, res: RefineResult) -> Correction:
        """The correction that takes the pose ``(R0, t0)`` to the refined one."""
        Rd = res.R @ np.asarray(R0, np.float64).T
        return Correction(res.R, res.t, Rd, res.t - Rd @ np.asarray(t0, np.float64), res)

    def refine(self, depth: np.ndarray, poses: list, active: list[bool],
               allowed: list[np.ndarray | None] | None = None,
               outlines: list[np.ndarray | None] | None = None,
               frame_depth: np.ndarray | None = None, short: list[bool] | None = None) -> list[Correction | None]:
        """Refine the ``active`` parts at ``poses[k] = (R, t)`` (None: part not rendered, e.g. not tracked) against
        ``depth``; ``allowed[k]``: optional H×W mask of the pixels part k may claim; ``outlines[k]``: optional
        polygon of part k's colour blob for the silhouette term (:mod:`tracker.refine.region_term`), which tests
        what hides an outline on ``frame_depth`` (``depth`` when None). Returns per
        part the accepted correction or None (inactive, not visible, not healthy or out of bounds; ``self.last``
        keeps each part's :class:`RefineResult` for loss detection and re-acquisition: a healthy one whose
        correction was out of bounds says so in its ``reason``). ``short[k]``: part k is refined with
        ``short_settings`` (e.g. its finest thresholds only) when those were given."""
        k = len(self.shapes)
        out: list[Correction | None] = [None] * k
        self.last = [None] * k
        bounds = [None if pose is None else self._bounds(i, pose) for i, pose in enumerate(poses)]
        rect = self._rect(poses, bounds)
        if rect is None:
            return out
        render = render_surfaces(self.intrinsics, self.shapes, poses, rect, self.stride)
        order = sorted((i for i in range(k) if active[i] and poses[i] is not None), key=lambda i: poses[i][1][2])
        for i in order:
            R0, t0 = (np.asarray(a, np.float64) for a in poses[i])
            body, nbody = render.body_points_of(i, self.intrinsics, R0, t0)  # (pts − t0) @ R0, nrm @ R0
            mask = None if allowed is None else allowed[i]
            settings = self.settings
            if short is not None and short[i] and self.short_settings is not None:
                settings = self.short_settings
            res = refine_pose(depth, self.intrinsics, body, nbody, R0, t0, self.centers[i], settings,
                              mask, self._region(poses, i, None if outlines is None else outlines[i],
                                                 depth if frame_depth is None else frame_depth, bounds, render))
            self.last[i] = res
            if not res.healthy:
                continue
            Rd = res.R @ R0.T
            c0 = R0 @ self.centers[i] + t0
            c1 = res.R @ self.centers[i] + res.t
            if np.linalg.norm(c1 - c0) > self.max_translation or rotation_angle(Rd) > self.max_rotation:
                res.reason = "correction beyond the accepted bounds"  # supported by the depth, but not taken here
                continue
            out[i] = Correction(res.R, res.t, Rd, res.t - Rd @ t0, res)
        return out


@nb.njit(cache=True)
def _corner_bounds(corners: np.ndarray, R: np.ndarray, t: np.ndarray, fx: float, fy: float, cx: float,
                   cy: float) -> tuple[float, float, float, float, bool]:
    """``(u_min, v_min, u_max, v_max, near)``: the pixel bounds of the body-frame points ``corners`` (M, 3) moved by
    ``(R, t)`` (body → camera, metres) and projected, and whether one lies closer than 2 cm to the camera plane.
    The values of ``corners @ R.T + t`` (each coordinate ``fma(c2, r2, fma(c1, r1, c0·r0)) + t``, as numpy's BLAS
    product of these shapes rounds here: :mod:`tracker.geometry.fma`), ``fx · x / z + cx`` and numpy's ``min`` /
    ``max`` (NaN when a coordinate is NaN)."""
    umin, vmin, umax, vmax = np.inf, np.inf, -np.inf, -np.inf
    nan_u = nan_v = near = False
    for i in range(corners.shape[0]):
        x, y, z = rigid_point(R, t, corners[i, 0], corners[i, 1], corners[i, 2])
        if z < 0.02:
            near = True
        u = fx * x / z + cx
        v = fy * y / z + cy
        if u != u:
            nan_u = True
        else:
            umin, umax = min(umin, u), max(umax, u)
        if v != v:
            nan_v = True
        else:
            vmin, vmax = min(vmin, v), max(vmax, v)
    if nan_u:
        umin = umax = np.nan
    if nan_v:
        vmin = vmax = np.nan
    return umin, vmin, umax, vmax, near


def _sampled_silhouette(render: SurfaceRender, obj: int, u0: int, v0: int, w: int, h: int) -> np.ndarray:
    """Part ``obj``'s visible silhouette over the image window ``(u0, v0)`` + ``(w, h)`` (bool (h, w)) from a strided
    render: each pixel takes the render's nearest sample (outside the render: not the part)."""
    i = np.rint((np.arange(u0, u0 + w) - render.u0) / render.stride).astype(np.int64)
    j = np.rint((np.arange(v0, v0 + h) - render.v0) / render.stride).astype(np.int64)
    return _gather_label(render.label, j, i, obj)


@nb.njit(cache=True)
def _gather_label(label: np.ndarray, rows: np.ndarray, cols: np.ndarray, obj: int) -> np.ndarray:
    """``label[rows[y], cols[x]] == obj`` for every ``(y, x)`` (False where an index falls outside ``label``)."""
    nv, nu = label.shape
    out = np.zeros((rows.shape[0], cols.shape[0]), np.bool_)
    for y in range(rows.shape[0]):
        r = rows[y]
        if r < 0 or r >= nv:
            continue
        for x in range(cols.shape[0]):
            c = cols[x]
            if 0 <= c < nu and label[r, c] == obj:
                out[y, x] = True
    return out
