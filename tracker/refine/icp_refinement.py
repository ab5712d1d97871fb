"""Optional point-to-plane ICP refinement of a well-visible part's estimate (the spec's "final ICP refinement",
section 17 future work).

The particle filter's likelihood runs on a subsampled depth image, which limits its precision (rotation
especially); ICP on the full-resolution points of the part's own colour blob (or, without colour, the points near
the estimate above the table) sharpens the estimate. Only small corrections are accepted, so a wrong
registration cannot carry the part away; the filter then shifts the part's particles by the same correction.
Camera frame, metres.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from tracker.geometry.camera import Intrinsics
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose


class PartSurfaceModel:
    """Surface samples (body frame) with normals and a k-d tree for nearest-point queries."""

    def __init__(self, part: PartSpec, n_points: int = 1200, seed: int = 0) -> None:
        mesh = part.load_mesh()
        # trimesh >= 4 draws from an unseeded default_rng unless given a seed (the global numpy state does not
        # matter): pass it explicitly, or every tracker instance gets different surface samples (non-deterministic
        # refinement)
        pts, faces = mesh.sample(n_points, return_index=True, seed=seed)
        self.points = np.asarray(pts, np.float64)
        self.normals = np.asarray(mesh.face_normals[faces], np.float64)
        self.tree = cKDTree(self.points)


def icp_refine(
    model: PartSurfaceModel,
    scene: np.ndarray,
    init: Pose,
    iterations: int = 8,
    max_corr: float = 0.01,
    min_points: int = 30,
) -> Pose | None:
    """Point-to-plane ICP of ``scene`` points (camera frame, (M, 3)) onto the part surface, from ``init``.

    Returns the refined part pose, or None when too few correspondences were found.
    """
    if scene.shape[0] < min_points:
        return None
    T = init.inverse().as_matrix()  # camera -> body
    for _ in range(iterations):
        q = scene @ T[:3, :3].T + T[:3, 3]
        dist, idx = model.tree.query(q, distance_upper_bound=max_corr)
        m = np.isfinite(dist)
        if m.sum() < min_points:
            return None
        qs, ps, ns = q[m], model.points[idx[m]], model.normals[idx[m]]
        A = np.hstack([np.cross(qs, ns), ns])
        b = np.einsum("ij,ij->i", ps - qs, ns)
        x, *_ = np.linalg.lstsq(A, b, rcond=None)
        T = Pose.from_rotvec(x[:3], x[3:]).as_matrix() @ T
        if np.linalg.norm(x) < 1e-5:
            break
    return Pose.from_matrix(np.linalg.inv(T))


def part_points(
    depth: np.ndarray,
    intrinsics: Intrinsics,
    estimate: Pose,
    radius: float,
    blob: np.ndarray | None,
    plane: tuple[np.ndarray, float] | None,
    stride: int = 2,
    table_band: float = 0.003,
    others: np.ndarray | None = None,
) -> np.ndarray:
    """Full-resolution depth points (every ``stride``-th pixel) for refining one part.

    With a colour ``blob`` mask (H×W bool) only its pixels are used; otherwise the points within ``radius`` of
    the estimate that are nearer to it than to any of the ``others`` (centres of the other parts, (K, 3)). Points
    within ``table_band`` of the table plane are dropped either way.
    """
    h, w = depth.shape
    uv = intrinsics.project(np.asarray(estimate.t)[None])[0]
    rpx = radius * intrinsics.fx / max(float(estimate.t[2]), 0.05)
    u0, u1 = int(max(0, np.floor(uv[0] - rpx))), int(min(w, np.ceil(uv[0] + rpx) + 1))
    v0, v1 = int(max(0, np.floor(uv[1] - rpx))), int(min(h, np.ceil(uv[1] + rpx) + 1))
    if u0 >= u1 or v0 >= v1:
        return np.zeros((0, 3))
    d = depth[v0:v1:stride, u0:u1:stride]
    vv, uu = np.mgrid[v0:v1:stride, u0:u1:stride]
    ok = np.isfinite(d) & (d > 0)
    if blob is not None:
        ok &= blob[v0:v1:stride, u0:u1:stride]
    pts = intrinsics.backproject(uu[ok], vv[ok], d[ok])
    dist = np.linalg.norm(pts - estimate.t, axis=1)
    keep = dist < radius
    if blob is None and others is not None and len(others):
        dmin = np.min(np.linalg.norm(pts[:, None, :] - np.asarray(others)[None], axis=2), axis=1)
        keep &= dist < dmin
    pts = pts[keep]
    if plane is not None:
        pts = pts[pts @ plane[0] + plane[1] > table_band]
    return pts
