"""Table plane from a depth image (the seed's Appendix A, spec section 3, plus a robust refinement).

Frames and units: camera frame (x right, y down, z forward), metres. The plane is ``n·p + d = 0`` with
``n`` the unit normal pointing to the camera's side ("up") and ``d = offset > 0`` (the camera centre is at
height ``d`` above the table). ``height(p) = n·p + d`` is the signed height (positive above the table).

Table frame (:meth:`TablePlane.table_to_camera`): origin where the camera's optical axis meets the plane (the
foot of the perpendicular from the camera when the axis is parallel to the plane); y axis = ``n``; x axis =
the camera x axis projected onto the plane, normalised; z = x × y (points roughly toward the camera/user).

Method (:func:`detect_table`):

1. Valid pixels: finite and > 0 depth (invalid pixels are excluded from M1, and so are pixels whose gradient
   stencil touches one). Isolated dropouts (more than half of their 5×5 neighbourhood valid) are first filled
   with the neighbourhood mean for the smoothness masks only (the fits use measured pixels only).
2. G = sqrt((S_x * I)² + (S_y * I)²) with the forward differences S_x = [-1 +1], S_y = [-1; +1] (A.1–A.2).
   M1 = G < t1·z: the threshold is **relative** to the depth z (``gradient_rel``, default t1 = 0.015 per pixel)
   because depth noise and the depth slope of an inclined plane both grow with distance. A plane seen 80° from
   its normal at fx = 525 px changes depth by ~1.1 % per pixel; a 3.6 cm step at 1 m by 3.6 %.
   Addition (not in the seed): M1 also requires a small second difference |z(u+4) − 2z(u) + z(u−4)| (and along
   v) of the 5×5 box-blurred depth, < ``curvature_rel``·z = 0.01·z. Without it a desk and the wall or panel
   behind it merge into one "smooth" region through their crease (seen on the TUM desk frame); an inclined plane
   has a second difference of only ~2(k·4)²·z for a relative slope k per pixel (0.004·z at 80° incidence).
3. D = distance transform of M1 (L2); M2 = D > t2 with ``dist_px`` t2 = 4 px at 640 px width (scaled with the
   image width) (A.4–A.5, corrected).
4. Region = the largest connected component of M2 (the interior of its largest external contour minus the
   holes of objects standing on it).
5. Plane: total least squares (SVD of the centred region points) — the general form n·q + d = 0, valid for
   a camera looking straight down (the seed's y = ax + bz + c is not).
6. Robust refinement on the back-projected points of the filled region contour (objects on the table and edge
   pixels are outliers): RANSAC (``ransac_iters`` = 120 three-point samples, seeded, inlier threshold
   ``ransac_threshold`` = 1 cm), then ``refine_iters`` = 4 rounds of SVD refits on the inliers with the
   threshold shrunk to max(2.5 × robust σ (MAD), ``min_threshold`` = 2 mm) but never above 1 cm.
7. Outline: the largest connected component (after a 5×5 closing) of all valid pixels within the inlier
   threshold of the final plane, as a simplified external polygon (``approxPolyDP``, 2 px).

``inlier_fraction`` = fraction of the filled region's valid points within the final threshold;
``residual_rms`` = RMS point-to-plane distance of those inliers (metres).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numba as nb
import numpy as np

from tracker.geometry.camera import Intrinsics
from tracker.geometry.pose import Pose


class TableNotFoundError(ValueError):
    """No table plane could be found in the depth image; the message says why."""


@dataclass(frozen=True)
class TableSettings:
    """Parameters of :func:`detect_table` (see the module docstring for their role)."""

    gradient_rel: float = 0.015
    """t1: smooth where |∇depth| < t1 · depth (per pixel, dimensionless)."""
    curvature_rel: float = 0.01
    """Crease test: smooth also needs |second difference over ±step| of the 5×5-blurred depth < this · depth
    (0 disables it; not in the seed)."""
    curvature_step_px: float = 4.0
    """Step of that second difference at 640 px width (pixels; scaled with width)."""
    dist_px: float = 4.0
    """t2 at 640 px image width (pixels; scaled with width): M2 = distance to the nearest edge > t2."""
    min_region_px: int = 500
    """Smallest acceptable smooth region (pixels at 640 px width, scaled with area)."""
    max_points: int = 20000
    """Points subsampled (deterministically) from the region for the fits."""
    ransac_iters: int = 120
    ransac_threshold: float = 0.01
    """Metres."""
    refine_iters: int = 4
    min_threshold: float = 0.002
    """Metres: floor of the adaptive inlier threshold used by the refinement."""
    seed: int = 0
    max_depth: float = 10.0
    """Depths beyond this (metres) are treated as invalid."""


@dataclass
class TablePlane:
    """A table plane ``normal·p + offset = 0`` in the camera frame (metres), normal up (toward the camera)."""

    normal: np.ndarray
    offset: float
    inlier_fraction: float = 1.0
    residual_rms: float = 0.0
    outline: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int32))
    n_points: int = 0
    _t2c: tuple | None = field(default=None, init=False, repr=False, compare=False)
    """:meth:`table_to_camera`'s last result with the normal's bytes and the offset it was made for."""

    def __post_init__(self) -> None:
        n = np.asarray(self.normal, np.float64).reshape(3)
        norm = float(np.linalg.norm(n))
        if not np.isfinite(norm) or norm < 1e-12 or not math.isfinite(float(self.offset)):
            raise ValueError(f"table plane: invalid normal {self.normal!r} or offset {self.offset!r}")
        n = n / norm
        d = float(self.offset) / norm
        if d < 0:  # orient the normal to the camera's side
            n, d = -n, -d
        self.normal = n
        self.offset = d
        self.outline = np.asarray(self.outline, np.int32).reshape(-1, 2)

    def height(self, points: np.ndarray) -> np.ndarray:
        """Signed heights (metres, positive above the table) of camera-frame points ``[..., 3]``."""
        return np.asarray(points, np.float64) @ self.normal + self.offset

    def origin(self) -> np.ndarray:
        """Origin of the table frame (camera frame, metres): the optical axis meets the plane there."""
        nz = self.normal[2]
        if abs(nz) > 1e-6:
            t = -self.offset / nz
            if t > 0:
                return np.array([0.0, 0.0, t])
        return -self.offset * self.normal

    def table_to_camera(self) -> Pose:
        """Pose of the table frame in the camera frame (maps table coordinates to camera coordinates); made once per
        normal and offset (the pipeline asks for it several times a frame)."""
        key = (np.asarray(self.normal, np.float64).tobytes(), float(self.offset))
        if self._t2c is not None and self._t2c[0] == key:
            return self._t2c[1]
        pose = self._table_to_camera()
        self._t2c = (key, pose)
        return pose

    def _table_to_camera(self) -> Pose:
        y = self.normal
        x = np.array([1.0, 0.0, 0.0]) - y[0] * y
        if np.linalg.norm(x) < 1e-6:  # camera x along the normal (camera rolled 90°): use camera z instead
            x = np.array([0.0, 0.0, 1.0]) - y[2] * y
        x = x / np.linalg.norm(x)
        z = np.cross(x, y)
        R = np.stack([x, y, z], axis=1)
        return Pose.from_rt(R, self.origin())

    def angle_to(self, other: TablePlane) -> float:
        """Angle between the two normals, radians."""
        return float(math.acos(float(np.clip(self.normal @ other.normal, -1.0, 1.0))))

    def to_dict(self, with_outline: bool = True) -> dict:
        d = {
            "normal": [float(v) for v in self.normal],
            "offset": float(self.offset),
            "inlier_fraction": float(self.inlier_fraction),
            "residual_rms": float(self.residual_rms),
            "n_points": int(self.n_points),
        }
        if with_outline:
            d["outline"] = self.outline.astype(int).tolist()
        return d

    @staticmethod
    def from_dict(d: dict) -> TablePlane:
        try:
            return TablePlane(
                normal=np.asarray(d["normal"], np.float64),
                offset=float(d["offset"]),
                inlier_fraction=float(d.get("inlier_fraction", 1.0)),
                residual_rms=float(d.get("residual_rms", 0.0)),
                outline=np.asarray(d.get("outline", np.zeros((0, 2))), np.int32),
                n_points=int(d.get("n_points", 0)),
            )
        except KeyError as exc:
            raise ValueError(f"table plane: missing field {exc.args[0]!r}") from exc
        except (TypeError, ValueError) as exc:
            raise ValueError(f"table plane {d!r}: {exc}") from exc


def table_changed(old: TablePlane, new: TablePlane, angle_tol: float = math.radians(2.0), offset_tol: float = 0.01):
    """True when the normals differ by more than ``angle_tol`` radians or the offsets by more than
    ``offset_tol`` metres (the camera or the table moved)."""
    return old.angle_to(new) > angle_tol or abs(old.offset - new.offset) > offset_tol


class TableMonitor:
    """Re-checks the table plane during a session.

    ``update(depth)`` re-detects the plane every ``every`` calls (the first call always detects) and returns
    True when it changed by more than the tolerances (see :func:`table_changed`); ``plane`` then holds the new
    plane. Frames where no table is found leave the plane unchanged.
    """

    def __init__(
        self,
        intrinsics: Intrinsics,
        settings: TableSettings | None = None,
        every: int = 30,
        angle_tol: float = math.radians(2.0),
        offset_tol: float = 0.01,
        plane: TablePlane | None = None,
    ) -> None:
        self.intrinsics = intrinsics
        self.settings = settings or TableSettings()
        self.every = max(1, int(every))
        self.angle_tol = angle_tol
        self.offset_tol = offset_tol
        self.plane = plane
        self._calls = 0

    def update(self, depth: np.ndarray | None) -> bool:
        due = self.plane is None or self._calls % self.every == 0
        self._calls += 1
        if not due or depth is None:
            return False
        try:
            new = detect_table(depth, self.intrinsics, self.settings)
        except TableNotFoundError:
            return False
        if self.plane is None:
            self.plane = new
            return False
        changed = table_changed(self.plane, new, self.angle_tol, self.offset_tol)
        if changed:
            self.plane = new
        return changed


# ---------------------------------------------------------------------------------------------- fitting
@nb.njit(cache=True, nogil=True)
def _centred(points):
    """``(points.mean(axis=0), points - mean)`` of float64 points ``[N, 3]``: the column sums in row order as numpy's
    reduction over axis 0 of a C-contiguous array takes them (the same values), without its strided passes."""
    n = points.shape[0]
    s0 = s1 = s2 = 0.0
    for i in range(n):
        s0 += points[i, 0]
        s1 += points[i, 1]
        s2 += points[i, 2]
    c = np.empty(3)
    c[0], c[1], c[2] = s0 / n, s1 / n, s2 / n
    q = np.empty((n, 3))
    for i in range(n):
        q[i, 0] = points[i, 0] - c[0]
        q[i, 1] = points[i, 1] - c[1]
        q[i, 2] = points[i, 2] - c[2]
    return c, q


def fit_plane_svd(points: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Total-least-squares plane ``n·p + d = 0`` through points ``[N, 3]`` (N ≥ 3)."""
    if weights is None and points.dtype == np.float64 and points.ndim == 2 and points.shape[1] == 3 and \
            points.flags.c_contiguous:  # (numpy's order of summation is the row order only for this layout)
        c, q = _centred(points)
    elif weights is None:
        c = points.mean(axis=0)
        q = points - c
    else:
        w = weights / weights.sum()
        c = (points * w[:, None]).sum(axis=0)
        q = (points - c) * np.sqrt(w)[:, None]
    _, _, vt = np.linalg.svd(q, full_matrices=False)
    n = vt[2]
    d = -float(n @ c)
    if d < 0:
        n, d = -n, -d
    return n, d


def _ransac(points: np.ndarray, thr: float, iters: int, rng: np.random.Generator) -> tuple[np.ndarray, float] | None:
    n_pts = len(points)
    idx = rng.integers(0, n_pts, size=(iters, 3))
    a, b, c = points[idx[:, 0]], points[idx[:, 1]], points[idx[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-9
    if not ok.any():
        return None
    normals = normals[ok] / norms[ok, None]
    ds = -np.einsum("ij,ij->i", normals, a[ok])
    # score hypotheses on a subsample for speed
    sub = points[:: max(1, n_pts // 4000)]
    counts = (np.abs(sub @ normals.T + ds[None, :]) < thr).sum(axis=0)
    best = int(np.argmax(counts))
    return normals[best], float(ds[best])


def _region(depth: np.ndarray, valid: np.ndarray, s: TableSettings, width: int):
    z = np.where(valid, depth, 0.0).astype(np.float32)
    # fill isolated dropouts (more than half of the 5×5 neighbourhood valid) for the smoothness masks only
    frac = cv2.blur(valid.astype(np.float32), (5, 5))
    zsum = cv2.blur(z, (5, 5))
    fill = ~valid & (frac > 0.5)
    z[fill] = zsum[fill] / frac[fill]
    measured = valid
    valid = valid | fill
    gx = np.zeros_like(z)
    gy = np.zeros_like(z)
    gx[:, :-1] = z[:, 1:] - z[:, :-1]
    gy[:-1, :] = z[1:, :] - z[:-1, :]
    vx = np.zeros_like(valid)
    vy = np.zeros_like(valid)
    vx[:, :-1] = valid[:, 1:] & valid[:, :-1]
    vy[:-1, :] = valid[1:, :] & valid[:-1, :]
    g = np.sqrt(gx * gx + gy * gy)
    m1 = valid & vx & vy & (g < s.gradient_rel * z)
    if s.curvature_rel > 0:
        # creases (a desk meeting a wall) have small gradients but a large second difference
        st = max(1, int(round(s.curvature_step_px * width / 640.0)))
        zb = cv2.blur(z, (5, 5))
        full = cv2.blur(valid.astype(np.float32), (5, 5)) > 0.999
        c = np.zeros_like(z)
        c[:, st:-st] = np.abs(zb[:, 2 * st :] - 2.0 * zb[:, st:-st] + zb[:, : -2 * st])
        cy = np.zeros_like(z)
        cy[st:-st, :] = np.abs(zb[2 * st :, :] - 2.0 * zb[st:-st, :] + zb[: -2 * st, :])
        m1 &= full & (np.maximum(c, cy) < s.curvature_rel * z)
    dist = cv2.distanceTransform(m1.astype(np.uint8), cv2.DIST_L2, 3)
    t2 = s.dist_px * width / 640.0
    m2 = (dist > t2).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(m2, connectivity=8)
    if n <= 1:
        return None, None
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    comp = (labels == k) & measured
    # the filled interior of the component's outer contour (objects standing on the table included)
    contours, _ = cv2.findContours(comp.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    filled = np.zeros(comp.shape, np.uint8)
    cv2.drawContours(filled, [max(contours, key=cv2.contourArea)], -1, 1, thickness=cv2.FILLED)
    return comp, filled.astype(bool) & measured


def plane_distance(depth: np.ndarray, intrinsics: Intrinsics, normal: np.ndarray, offset: float,
                   step: int = 1) -> np.ndarray:
    """Signed distance (metres, float32) of every ``step``-th pixel's back-projected point (rows and columns) to the
    plane ``normal · x + offset = 0`` (camera frame): ``z · (normal · ray) + offset`` with the pixel's ray
    ``((u - cx) / fx, (v - cy) / fy, 1)``, without building the point image; NaN where the depth is."""
    z = np.asarray(depth, np.float32)[::step, ::step]
    u = np.arange(0, depth.shape[1], step, dtype=np.float32)[None, :]
    v = np.arange(0, depth.shape[0], step, dtype=np.float32)[:, None]
    n = np.asarray(normal, np.float32)
    dots = n[0] * (u - intrinsics.cx) / intrinsics.fx + n[1] * (v - intrinsics.cy) / intrinsics.fy + n[2]
    return z * dots + np.float32(offset)


def _subsample(mask: np.ndarray, max_points: int) -> tuple[np.ndarray, np.ndarray]:
    vs, us = np.nonzero(mask)
    step = max(1, int(math.ceil(len(us) / max_points)))
    return us[::step], vs[::step]


def detect_table(depth: np.ndarray, intrinsics: Intrinsics, settings: TableSettings | None = None) -> TablePlane:
    """Detect the table as the largest smooth surface of a depth image (metres, NaN or 0 = missing).

    Raises :class:`TableNotFoundError` when the depth has no valid pixels, no smooth region large enough, or
    the fitted plane is degenerate.
    """
    s = settings or TableSettings()
    if not isinstance(depth, np.ndarray) or depth.ndim != 2:
        raise TableNotFoundError(f"table detection: depth must be a HxW array, got {getattr(depth, 'shape', None)}")
    h, w = depth.shape
    if (w, h) != (intrinsics.width, intrinsics.height):
        raise TableNotFoundError(
            f"table detection: depth is {w}x{h} but the intrinsics are {intrinsics.width}x{intrinsics.height}"
        )
    depth = depth.astype(np.float32, copy=False)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(depth) & (depth > 0) & (depth < s.max_depth)
    n_valid = int(valid.sum())
    if n_valid == 0:
        raise TableNotFoundError("table detection: the depth image has no valid pixels (all missing/zero)")
    min_region = max(30, int(s.min_region_px * (w * h) / (640 * 480)))
    comp, filled = _region(depth, valid, s, w)
    if comp is None or int(comp.sum()) < min_region:
        raise TableNotFoundError(
            f"table detection: no smooth depth region of at least {min_region} pixels "
            f"({n_valid} valid pixels; gradient threshold t1={s.gradient_rel}·z, edge distance t2={s.dist_px} px)"
        )
    # 5. initial total-least-squares plane on the smooth region
    us, vs = _subsample(comp, s.max_points)
    pts0 = intrinsics.backproject(us, vs, depth[vs, us])
    n, d = fit_plane_svd(pts0)
    # 6. RANSAC + inlier refits on the filled region (objects on the table are outliers)
    us, vs = _subsample(filled, s.max_points)
    pts = intrinsics.backproject(us, vs, depth[vs, us])
    rng = np.random.default_rng(s.seed)
    cand = _ransac(pts, s.ransac_threshold, s.ransac_iters, rng)
    if cand is not None:
        cnt_cand = int((np.abs(pts @ cand[0] + cand[1]) < s.ransac_threshold).sum())
        cnt_ls = int((np.abs(pts @ n + d) < s.ransac_threshold).sum())
        if cnt_cand > cnt_ls:
            n, d = cand
    thr = s.ransac_threshold
    inl = np.abs(pts @ n + d) < thr
    for _ in range(s.refine_iters):
        if inl.sum() < 3:
            break
        n, d = fit_plane_svd(pts[inl])
        r = pts @ n + d
        ri = r[inl]
        sigma = 1.4826 * float(np.median(np.abs(ri - np.median(ri))))
        thr = float(np.clip(2.5 * sigma, s.min_threshold, s.ransac_threshold))
        inl = np.abs(r) < thr
    if inl.sum() < 3:
        raise TableNotFoundError("table detection: the plane fit found fewer than 3 inliers")
    r = pts @ n + d
    plane_n, plane_d = n, d
    if plane_d < 0:
        plane_n, plane_d = -plane_n, -plane_d
    if plane_d < 1e-4:
        raise TableNotFoundError("table detection: the fitted plane passes through the camera centre")
    # 7. outline of the table region in the image
    near = valid & (np.abs(plane_distance(depth, intrinsics, plane_n, plane_d)) < max(thr, 0.005))
    near_u8 = cv2.morphologyEx(near.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    outline = np.zeros((0, 2), np.int32)
    contours, _ = cv2.findContours(near_u8, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if contours:
        c = max(contours, key=cv2.contourArea)
        outline = cv2.approxPolyDP(c, 2.0, True).reshape(-1, 2)
    return TablePlane(
        normal=plane_n,
        offset=plane_d,
        inlier_fraction=float(inl.mean()),
        residual_rms=float(np.sqrt(np.mean(r[inl] ** 2))),
        outline=outline,
        n_points=int(len(pts)),
    )


def plane_share(
    depth: np.ndarray, intrinsics: Intrinsics, plane: TablePlane, step: int = 8, tolerance: float = 0.005
) -> float:
    """Share (0..1) of a coarse grid of depth pixels (every ``step``-th row and column, missing ones included)
    lying within ``tolerance`` metres of ``plane``: a cheap per-frame test that the plane still fits the depth.

    Compare it with the share right after detection: when the camera (or the table) moves, it drops (a 1 cm
    shift along the normal takes almost every pixel off the plane), and the plane should be detected again.
    """
    with np.errstate(invalid="ignore"):
        on = np.abs(plane_distance(depth, intrinsics, plane.normal, plane.offset, step)) < tolerance
    return float(np.count_nonzero(on)) / max(1, on.size)
