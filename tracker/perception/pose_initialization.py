"""Automatic first-frame pose initialisation of parts resting on the table (camera frame, metres).

:func:`initialize_poses` finds, in one RGB-D frame, the pose of every part that stands on the table in one of
its resting orientations, so that the depth tracker can start without a hand-written ``pose`` in objects.json.

Method (per frame):

1. Table plane ``n·p + d = 0`` (:func:`tracker.perception.table_plane.detect_table` unless given); heights above it
   ``h = n·p + d`` (positive toward the camera).
2. Above-table mask: pixels with ``min_height < h < max_height`` (``min_height`` = max(``min_height``,
   ``rms_factor`` × the plane's RMS residual), so table noise and paper on the table are not objects), cleaned
   with a morphological opening and split into connected components (``cv2.connectedComponentsWithStats``);
   components under ``min_area_px`` pixels are dropped.
3. Candidate points per part:
   - coloured part (``part.color`` set and colour used): the pixels of its colour blob (largest contour of
     ``ColorDetector.from_parts(parts).detect(rgb)``, dilated by 2 px) ∩ the above-table mask;
   - uncoloured part: one connected component, assigned to the parts by ``linear_sum_assignment`` on a cost of
     relative footprint and height differences (footprint = ``cv2.minAreaRect`` of the component's points in
     table coordinates (x, z) without stray points, height = 98th percentile of their heights above the local
     support); a border-touching component costs 0.5 more. A component whose footprint area is about k ≥ 2
     part footprints (touching parts) is split into k pieces by k-means of its table coordinates when the
     pieces match the parts' sizes better than the whole.
4. Local support: the median height of the table points in a ring around the candidate (the part may stand
   on a sheet of paper or a notebook a few millimetres above the fitted plane).
5. Initial pose: the table's orientation (body y = table normal) turned about the normal by the yaw of the
   footprint rectangle (for boxes/meshes whose bounding box is not square, the footprint's long side along the
   body's longer horizontal axis); position = footprint centre lifted so that the part's bounding box rests on
   the support. Boxes may rest on any face: the face whose height above the support matches the measured height
   best is chosen (body y up on ties).
6. Refinement: point-to-plane ICP (:func:`tracker.refine.icp_refinement.icp_refine`, box or mesh surface model),
   coarse-to-fine correspondence distances. The refined pose is kept only when it stays close to resting
   (tilt < ``max_tilt``) and lowers the residual; otherwise it is snapped back to the nearest resting pose.

``residual_mm`` is the median point-to-plane distance (mm) of the candidate points to the part surface at the
returned pose (nearest surface sample and its normal).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.cluster.vq import kmeans2
from scipy.optimize import linear_sum_assignment

from tracker.frame import Frame
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose
from tracker.perception.table_plane import TableNotFoundError, TablePlane, detect_table
from tracker.refine.icp_refinement import PartSurfaceModel, icp_refine


@dataclass(frozen=True)
class InitSettings:
    """Parameters of :func:`initialize_poses` (metres, pixels at the frame's resolution)."""

    min_height: float = 0.005
    """Points must be at least this high above the table to count as object points."""
    rms_factor: float = 2.5
    """... and at least this many times the table plane's RMS residual."""
    max_height: float = 0.3
    open_px: int = 5
    """Side of the square opening kernel applied to the above-table mask."""
    min_area_px: int = 60
    """Components (or blob ∩ mask regions) smaller than this are ignored."""
    outlier_factor: float = 1.2
    """Footprint points farther from the median than this × the 97th percentile distance are ignored."""
    ring_px: int = 12
    """Width of the ring around a candidate in which the local support height is measured."""
    support_band: float = 0.012
    """Ring points within this height of the table plane count as support."""
    max_cost: float = 1.0
    """Largest accepted footprint/height cost of an uncoloured assignment (sum of relative differences)."""
    max_tilt: float = math.radians(12.0)
    """ICP results tilting the part more than this from a resting orientation are snapped back."""
    icp_points: int = 4000
    """Surface samples of the part model used by ICP and the residual."""
    max_scene_points: int = 3000


@dataclass
class InitResult:
    """First-frame pose of one part: ``pose`` (body → camera), ``residual_mm`` (median point-to-surface
    distance of the ``n_points`` depth points used, millimetres) and ``method`` (how it was found)."""

    pose: Pose
    residual_mm: float
    n_points: int
    method: str


def _resting_options(part: PartSpec) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """Resting orientations of the part's bounding box: (R_rest body→table-upright, bbox centre (body), height).

    ``R_rest`` maps body coordinates to an upright frame whose y axis is up; the fundamental orientation
    (body y up) comes first.
    """
    if part.box is not None:
        lo, hi = -np.asarray(part.box, float) / 2, np.asarray(part.box, float) / 2
    else:
        v = part.vertices()
        lo, hi = v.min(axis=0), v.max(axis=0)
    centre, size = (lo + hi) / 2, hi - lo
    eye = np.eye(3)
    # body axis k up: permutations keeping right-handedness
    options = [(eye, centre, float(size[1]))]
    if part.box is not None and not part.is_cube:
        Rx = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # body z up
        Rz = np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 1]])  # body x up
        options += [(Rx, centre, float(size[2])), (Rz, centre, float(size[0]))]
    return options


def _bbox_corners(part: PartSpec) -> np.ndarray:
    """The 8 corners (body frame, metres) of the part's axis-aligned bounding box."""
    v = part.vertices()
    lo, hi = v.min(axis=0), v.max(axis=0)
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def _footprint_dims(R_rest: np.ndarray, part: PartSpec) -> tuple[float, float]:
    """Horizontal extents (along upright x, z) of the part's bounding box in a resting orientation."""
    if part.box is not None:
        size = np.asarray(part.box, float)
    else:
        v = part.vertices()
        size = v.max(axis=0) - v.min(axis=0)
    s = np.abs(R_rest) @ size
    return float(s[0]), float(s[2])


@dataclass
class _Candidate:
    mask: np.ndarray  # H×W bool
    points: np.ndarray  # (M, 3) camera frame
    rect: tuple  # minAreaRect in table (x, z) coordinates
    height: float  # measured top height above the local support
    support: float  # local support height above the table plane
    border: bool  # touches the image border


def _above_table_mask(points: np.ndarray, table: TablePlane, s: InitSettings) -> tuple[np.ndarray, np.ndarray]:
    h = table.height(points)
    lo = max(s.min_height, s.rms_factor * float(table.residual_rms))
    with np.errstate(invalid="ignore"):
        m = np.isfinite(h) & (h > lo) & (h < s.max_height)
    m = cv2.morphologyEx(m.astype(np.uint8), cv2.MORPH_OPEN, np.ones((s.open_px, s.open_px), np.uint8))
    return m.astype(bool), h


def _candidate(mask: np.ndarray, points: np.ndarray, heights: np.ndarray, table_pts: np.ndarray,
               s: InitSettings) -> _Candidate:
    """Footprint, height and support of the object pixels in ``mask``."""
    T_inv = table_pts  # 3×4: camera -> table
    pts = points[mask]
    tp = pts @ T_inv[:, :3].T + T_inv[:, 3]
    xz = tp[:, [0, 2]]
    # drop stray points (flying pixels between an edge and the background) before fitting the rectangle
    d = np.linalg.norm(xz - np.median(xz, axis=0), axis=1)
    xz = xz[d <= s.outlier_factor * np.percentile(d, 97)]
    rect = cv2.minAreaRect(xz.astype(np.float32))
    k = np.ones((2 * s.ring_px + 1, 2 * s.ring_px + 1), np.uint8)
    ring = cv2.dilate(mask.astype(np.uint8), k).astype(bool) & ~mask
    hr = heights[ring]
    with np.errstate(invalid="ignore"):
        hr = hr[np.isfinite(hr) & (np.abs(hr) < s.support_band)]
    support = float(np.median(hr)) if hr.size >= 20 else 0.0
    top = float(np.percentile(heights[mask], 98)) - support
    h_img, w_img = mask.shape
    ys, xs = np.nonzero(mask)
    border = bool(xs.min() <= 1 or ys.min() <= 1 or xs.max() >= w_img - 2 or ys.max() >= h_img - 2)
    return _Candidate(mask, pts, rect, top, support, border)


def _cost(part: PartSpec, c: _Candidate) -> float:
    """Relative footprint + height mismatch of a part (best resting orientation) and a candidate."""
    (_, _), (a, b), _ = c.rect
    meas = sorted([a, b])
    best = math.inf
    for R_rest, _centre, height in _resting_options(part):
        fx, fz = _footprint_dims(R_rest, part)
        ref = sorted([fx, fz])
        cost = abs(meas[0] - ref[0]) / ref[0] + abs(meas[1] - ref[1]) / ref[1] + abs(c.height - height) / height
        best = min(best, cost)
    return best + (0.5 if c.border else 0.0)


def _split_touching(c: _Candidate, plain: list[PartSpec], points: np.ndarray, heights: np.ndarray,
                    cam_to_table: np.ndarray, s: InitSettings) -> list[_Candidate]:
    """Split a component holding several touching parts (footprint area ≈ k part footprints, k ≥ 2) into k
    pieces by k-means of its table (x, z) coordinates; kept when the pieces match the parts better."""
    (_, _), (a, b), _ = c.rect
    areas = [fx * fz for p in plain for R, _, _ in _resting_options(p) for fx, fz in [_footprint_dims(R, p)]]
    k = min(int(round(a * b / min(areas))), len(plain))
    if k < 2:
        return [c]
    tp = c.points @ cam_to_table[:, :3].T + cam_to_table[:, 3]
    xz = tp[:, [0, 2]]
    _, labels = kmeans2(xz, k, seed=np.random.default_rng(0), minit="++")
    vs, us = np.nonzero(c.mask)
    pieces = []
    for j in range(k):
        m = np.zeros_like(c.mask)
        m[vs[labels == j], us[labels == j]] = True
        if m.sum() < s.min_area_px:
            return [c]
        pieces.append(_candidate(m, points, heights, cam_to_table, s))
    whole = min(_cost(p, c) for p in plain)
    split = float(np.mean([min(_cost(p, q) for p in plain) for q in pieces]))
    return pieces if split < whole else [c]


def _initial_pose(part: PartSpec, c: _Candidate, table: TablePlane) -> Pose:
    """Resting pose from the footprint rectangle: body y (or the resting up axis) along the table normal."""
    (cx, cz), (a, b), angle = c.rect
    th = math.radians(angle)
    e1 = np.array([math.cos(th), math.sin(th)])  # side of length a, in table (x, z)
    e2 = np.array([-math.sin(th), math.cos(th)])  # side of length b
    best = None
    for R_rest, centre, height in _resting_options(part):
        err = abs(c.height - height)
        if best is None or err < best[0] - 1e-3:  # fundamental orientation first on ties
            best = (err, R_rest, centre, height)
    _, R_rest, centre, height = best
    fx, fz = _footprint_dims(R_rest, part)
    # upright x along the rectangle side whose length matches fx best
    long_is_a = a >= b
    ex2 = (e1 if long_is_a else e2) if fx >= fz else (e2 if long_is_a else e1)
    ex = np.array([ex2[0], 0.0, ex2[1]])
    ey = np.array([0.0, 1.0, 0.0])
    ez = np.cross(ex, ey)
    R_up = np.stack([ex, ey, ez], axis=1)  # upright -> table
    R_body_table = R_up @ R_rest
    # lift: the bounding box centre (body) sits at half the resting height above the support
    c_table = np.array([cx, c.support + height / 2.0, cz])
    t_table = c_table - R_body_table @ centre
    T = table.table_to_camera().as_matrix()
    R = T[:3, :3] @ R_body_table
    t = T[:3, :3] @ t_table + T[:3, 3]
    return Pose.from_rt(R, t)


def _residual(model: PartSurfaceModel, pts: np.ndarray, pose: Pose) -> float:
    """Median point-to-plane distance (metres) of camera-frame points to the part surface at ``pose``."""
    q = pose.inverse().transform_points(pts)
    _, idx = model.tree.query(q)
    d = np.abs(np.einsum("ij,ij->i", q - model.points[idx], model.normals[idx]))
    return float(np.median(d))


def _snap_to_rest(part: PartSpec, pose: Pose, table: TablePlane, support: float) -> tuple[Pose, float]:
    """Nearest resting pose: the body axis closest to the table normal turned onto it, bottom on the support.

    Returns the pose and the tilt (radians) that was removed.
    """
    n = table.normal
    R = pose.R
    best = None
    for R_rest, centre, height in _resting_options(part):
        up_body = R_rest.T @ np.array([0.0, 1.0, 0.0])  # body direction that is up in this resting orientation
        up_cam = R @ up_body
        tilt = math.acos(float(np.clip(up_cam @ n, -1.0, 1.0)))
        if best is None or tilt < best[0]:
            best = (tilt, up_cam, centre, height)
    tilt, up_cam, centre, height = best
    axis = np.cross(up_cam, n)
    s = float(np.linalg.norm(axis))
    R_fix = np.eye(3) if s < 1e-12 else Pose.from_rotvec(axis / s * math.atan2(s, float(up_cam @ n)),
                                                         np.zeros(3)).R
    R_new = R_fix @ R
    c_cam = R @ centre + pose.t
    h = float(table.height(c_cam[None])[0])
    c_cam = c_cam + n * (support + height / 2.0 - h)
    return Pose.from_rt(R_new, c_cam - R_new @ centre), tilt


def _refine(part: PartSpec, model: PartSurfaceModel, c: _Candidate, init: Pose, table: TablePlane,
            s: InitSettings) -> tuple[Pose, float, str]:
    pts = c.points
    if pts.shape[0] > s.max_scene_points:
        pts = pts[np.linspace(0, pts.shape[0] - 1, s.max_scene_points).astype(int)]
    pose = init
    method = "footprint"
    for max_corr, iters in ((0.02, 15), (0.008, 15), (0.004, 10)):
        r = icp_refine(model, pts, pose, iterations=iters, max_corr=max_corr)
        if r is not None:
            pose = r
            method = "footprint+icp"
    if method != "footprint":
        snapped, tilt = _snap_to_rest(part, pose, table, c.support)
        if tilt > s.max_tilt:
            pose = snapped
            method = "footprint+icp+snap"
    res_init, res = _residual(model, pts, init), _residual(model, pts, pose)
    if res > res_init:
        pose, res, method = init, res_init, "footprint"
    return pose, res, method


def initialize_poses(
    frame: Frame,
    parts: Sequence[PartSpec],
    table: TablePlane | None = None,
    detections: Mapping | None = None,
    use_color: bool = True,
    settings: InitSettings | None = None,
    known: Mapping[str, tuple[PartSpec, Pose]] | None = None,
) -> dict[str, InitResult]:
    """First-frame poses (camera frame) of ``parts`` resting on the table in ``frame``.

    ``table``: the table plane (detected from the frame's depth when None). ``detections``: per-part
    :class:`~tracker.perception.color_detection.ColorDetection` (computed from the frame's colour image for the coloured
    parts when None). ``use_color=False`` treats every part as uncoloured. Raises ValueError naming the part and
    the reason when a pose cannot be found (no depth, no table, no object above the table, no blob of the
    part's colour, fewer objects than parts). ``known``: parts whose poses are already known (name → (part,
    pose)); the pixels of their projected bounding boxes are not used for the others.
    """
    s = settings or InitSettings()
    parts = list(parts)
    if not parts:
        return {}
    names = [p.name for p in parts]
    if frame.depth is None:
        raise ValueError(f"pose initialisation of {names}: frame {frame.index} has no depth image")
    intr = frame.intrinsics
    if table is None:
        try:
            table = detect_table(frame.depth, intr)
        except TableNotFoundError as exc:
            raise ValueError(f"pose initialisation of {names}: no table plane in frame {frame.index}: {exc}") from exc
    points = intr.depth_to_points(frame.depth)
    mask, heights = _above_table_mask(points, table, s)
    if mask.sum() < s.min_area_px:
        raise ValueError(f"pose initialisation of {names}: nothing stands above the table in frame {frame.index}")
    for kpart, kpose in (known or {}).values():
        uv = intr.project(kpose.transform_points(_bbox_corners(kpart)))
        if np.all(np.isfinite(uv)):
            hull = cv2.convexHull(np.round(uv).astype(np.int32).reshape(-1, 1, 2))
            sil = np.zeros(mask.shape, np.uint8)
            cv2.fillConvexPoly(sil, hull, 1)
            mask &= ~cv2.dilate(sil, np.ones((7, 7), np.uint8)).astype(bool)
    cam_to_table = table.table_to_camera().inverse().as_matrix()[:3]

    colored = [p for p in parts if use_color and p.color is not None]
    plain = [p for p in parts if not (use_color and p.color is not None)]
    cands: dict[str, _Candidate] = {}
    taken = np.zeros_like(mask)
    if colored:
        if detections is None:
            from tracker.perception.color_detection import ColorDetector

            detections = ColorDetector.from_parts(colored).detect(frame.color)
        for p in colored:
            det = detections.get(p.name)
            if det is None or not det.detected or det.contour is None:
                raise ValueError(f"pose initialisation of part {p.name!r}: no blob of its colour {p.color} "
                                 f"in frame {frame.index}")
            blob = np.zeros(mask.shape, np.uint8)
            cv2.drawContours(blob, [np.asarray(det.contour, np.int32).reshape(-1, 1, 2)], -1, 1, cv2.FILLED)
            blob = cv2.dilate(blob, np.ones((5, 5), np.uint8)).astype(bool)
            m = blob & mask
            if m.sum() < s.min_area_px:
                raise ValueError(f"pose initialisation of part {p.name!r}: its colour blob has no depth points "
                                 f"above the table in frame {frame.index}")
            cands[p.name] = _candidate(m, points, heights, cam_to_table, s)
            taken |= blob
    if plain:
        n_lab, lab, stats, _ = cv2.connectedComponentsWithStats((mask & ~taken).astype(np.uint8), connectivity=8)
        comps = []
        for i in range(1, n_lab):
            if stats[i, cv2.CC_STAT_AREA] >= s.min_area_px:
                comps += _split_touching(_candidate(lab == i, points, heights, cam_to_table, s), plain, points,
                                         heights, cam_to_table, s)
        if len(comps) < len(plain):
            raise ValueError(f"pose initialisation of {[p.name for p in plain]}: only {len(comps)} object(s) "
                             f"above the table in frame {frame.index} for {len(plain)} uncoloured part(s)")
        cost = np.array([[_cost(p, c) for c in comps] for p in plain])
        rows, cols = linear_sum_assignment(cost)
        for r, c in zip(rows, cols, strict=True):
            p = plain[r]
            if cost[r, c] > s.max_cost:
                (_, _), (a, b), _ = comps[c].rect
                raise ValueError(f"pose initialisation of part {p.name!r}: no object above the table matches its "
                                 f"size in frame {frame.index} (best: footprint {1000 * a:.0f}x{1000 * b:.0f} mm, "
                                 f"height {1000 * comps[c].height:.0f} mm)")
            cands[p.name] = comps[c]

    out: dict[str, InitResult] = {}
    for p in parts:
        c = cands[p.name]
        model = PartSurfaceModel(p, n_points=s.icp_points, seed=0)
        init = _initial_pose(p, c, table)
        pose, res, method = _refine(p, model, c, init, table, s)
        kind = "colour" if p in colored else "depth"
        out[p.name] = InitResult(pose=pose, residual_mm=1000.0 * res, n_points=int(c.points.shape[0]),
                                 method=f"{kind}:{method}")
    return out
