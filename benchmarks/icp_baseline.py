"""Baseline a user might pick instead of the particle filter: frame-to-frame point-to-plane ICP per part.

For each part, each frame: take the depth points within a sphere around the previous estimate (radius =
part bounding radius + ``crop_margin``), minus the table points (within ``table_band`` of the plane) when a
table plane is given, register the part's surface model (points with normals sampled on its
mesh, seeded: a run is repeatable) to them with point-to-plane ICP, starting from the previous estimate. Uses
Open3D when it is installed (optional benchmark-only dependency, the ``bench`` extra: ``pip install -e .[bench]``),
else a numpy/scipy implementation (``backend`` says which).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from tracker.geometry.camera import Intrinsics
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose

try:  # optional
    import open3d as o3d  # type: ignore

    HAVE_OPEN3D = True
except Exception:  # pragma: no cover - depends on the environment
    o3d = None
    HAVE_OPEN3D = False


def _surface_model(part: PartSpec, n: int = 1500, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points (body frame, metres) sampled uniformly on the part's surface (seeded) and their face normals."""
    mesh = part.load_mesh()
    pts, faces = mesh.sample(n, return_index=True, seed=seed)
    return np.asarray(pts, np.float64), np.asarray(mesh.face_normals[faces], np.float64)


class ICPTracker:
    """Per-part frame-to-frame point-to-plane ICP (camera frame, metres)."""

    def __init__(self, parts: list[PartSpec], intrinsics: Intrinsics, crop_margin: float = 0.02,
                 iterations: int = 15, max_corr: float = 0.015, stride: int = 2, use_open3d: bool = True) -> None:
        self.parts = parts
        self.intr = intrinsics
        self.models = {p.name: _surface_model(p) for p in parts}
        self.radius = {p.name: p.bounding_radius() + crop_margin for p in parts}
        self.iterations = iterations
        self.max_corr = max_corr
        self.stride = stride
        self.backend = "open3d" if (use_open3d and HAVE_OPEN3D) else "numpy/scipy"
        self.poses: dict[str, Pose] = {}

    def initialize(self, poses: dict[str, Pose]) -> None:
        self.poses = dict(poses)

    def step(self, depth: np.ndarray, table: tuple[np.ndarray, float] | None = None,
             table_band: float = 0.004) -> dict[str, Pose]:
        """Register every part to ``depth`` (metres); ``table`` = (normal, offset) removes the table points."""
        s = self.stride
        d = depth[::s, ::s]
        v, u = np.mgrid[0:depth.shape[0]:s, 0:depth.shape[1]:s]
        ok = np.isfinite(d) & (d > 0)
        pts = self.intr.backproject(u[ok], v[ok], d[ok])
        if table is not None:
            n, off = np.asarray(table[0], np.float64), float(table[1])
            pts = pts[pts @ n + off > table_band]
        for p in self.parts:
            prev = self.poses[p.name]
            near = pts[np.linalg.norm(pts - prev.t, axis=1) < self.radius[p.name]]
            if near.shape[0] < 20:
                continue
            self.poses[p.name] = self._register(p.name, near, prev)
        return dict(self.poses)

    def _register(self, name: str, scene: np.ndarray, init: Pose) -> Pose:
        model_pts, model_nrm = self.models[name]
        if self.backend == "open3d":
            src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scene))
            tgt = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(model_pts))
            tgt.normals = o3d.utility.Vector3dVector(model_nrm)
            # scene (camera frame) -> model (body frame): initial transform = init⁻¹
            res = o3d.pipelines.registration.registration_icp(
                src, tgt, self.max_corr, init.inverse().as_matrix(),
                o3d.pipelines.registration.TransformationEstimationPointToPlane(),
                o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=self.iterations),
            )
            return Pose.from_matrix(np.linalg.inv(res.transformation))
        tree = cKDTree(model_pts)
        T = init.inverse().as_matrix()  # camera -> body
        for _ in range(self.iterations):
            q = scene @ T[:3, :3].T + T[:3, 3]
            dist, idx = tree.query(q, distance_upper_bound=self.max_corr)
            m = np.isfinite(dist)
            if m.sum() < 10:
                break
            qs, ps, ns = q[m], model_pts[idx[m]], model_nrm[idx[m]]
            # linearised point-to-plane: minimise Σ ((q + w×q + t − p)·n)²
            A = np.hstack([np.cross(qs, ns), ns])
            b = np.einsum("ij,ij->i", ps - qs, ns)
            x, *_ = np.linalg.lstsq(A, b, rcond=None)
            dT = Pose.from_rotvec(x[:3], x[3:]).as_matrix()
            T = dT @ T
            if np.linalg.norm(x) < 1e-6:
                break
        return Pose.from_matrix(np.linalg.inv(T))
