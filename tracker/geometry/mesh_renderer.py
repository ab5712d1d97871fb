"""Depth rendering of triangle meshes (OBJ/PLY/STL via trimesh) at the likelihood resolution, with numba.

Triangles are projected and rasterised (perspective-correct z by interpolating 1/z) into a small z-buffer
covering the evaluated pixels' bounding rectangle on the downsampled grid, then read out at the evaluated
pixels. Depth is camera-frame z in metres, ``inf`` = no surface. The downsampled grid has pixel ``(i, j)``
at full-resolution coordinates ``(off + f·i, off + f·j)`` with ``off = (f − 1) // 2``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from tracker.geometry.box_renderer import copy_depth_row, same_pose
from tracker.geometry.parts import PartSpec


@dataclass(frozen=True)
class MeshModel:
    """A part's triangle mesh in its body frame (metres): ``vertices`` (V, 3) float64, ``faces`` (F, 3) int64."""

    vertices: np.ndarray
    faces: np.ndarray

    @staticmethod
    def from_part(part: PartSpec, max_faces: int = 2000) -> MeshModel:
        """Load (and if needed simplify) the part's mesh; raise ``ValueError`` naming the file on failure."""
        try:
            mesh = part.load_mesh()
        except FileNotFoundError:
            raise
        except Exception as exc:  # trimesh raises many types on bad files
            raise ValueError(f"part {part.name!r}: cannot load mesh {part.mesh!r}: {exc}") from exc
        faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), np.int64)
        verts = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), np.float64)
        if faces.size == 0 or verts.size == 0:
            raise ValueError(f"part {part.name!r}: mesh {part.mesh!r} has no triangles")
        if len(faces) > max_faces:
            try:
                simple = mesh.simplify_quadric_decimation(face_count=max_faces)
                faces = np.asarray(simple.faces, np.int64)
                verts = np.asarray(simple.vertices, np.float64)
            except Exception:  # optional dependency of trimesh; keep the full mesh
                pass
        return MeshModel(verts, faces)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Body-frame axis-aligned bounding box: centre (3,) and half extents (3,)."""
        lo = self.vertices.min(axis=0)
        hi = self.vertices.max(axis=0)
        return (lo + hi) / 2.0, (hi - lo) / 2.0


@nb.njit(cache=True)
def render_mesh_at_pixels(R, t, vertices, faces, obj, particles, gi, gj, subset, f, off, fx, fy, cx, cy, out, loc,
                          dirty, lattice=1):
    """Render mesh ``obj`` for the listed particles at the listed pixels into ``out[j, loc[obj, i]]``.

    * ``R`` (N, K, 3, 3), ``t`` (N, K, 3): body→camera poses; ``vertices`` (V, 3), ``faces`` (F, 3).
    * ``gi``/``gj`` (P,) downsampled-grid column/row of each evaluated pixel; ``subset`` (S,) pixel indices.
    * ``f``/``off``: downsampling factor and offset of the grid (full-res u = off + f·gi).
    * ``out`` (N, M) depth columns, ``loc`` (K, P) column of part k at pixel i or −1 (see the box renderer).
    * ``dirty`` (N, P) uint8: set to 1 where a written depth differs from the previous one.
    * ``lattice``: rasterise only every ``lattice``-th grid pixel in each axis (a pixel off that lattice reads the
      nearest lattice pixel's depth); for large parts whose evaluated pixels were thinned to that lattice.

    A particle whose pose equals the previous listed particle's takes its depths without rasterising again.
    """
    if subset.shape[0] == 0:
        return
    i0 = gi[subset[0]]
    i1 = i0
    j0 = gj[subset[0]]
    j1 = j0
    for ii in range(subset.shape[0]):
        i = subset[ii]
        i0 = min(i0, gi[i])
        i1 = max(i1, gi[i])
        j0 = min(j0, gj[i])
        j1 = max(j1, gj[i])
    lat = max(lattice, 1)
    half_lat = lat // 2
    i0 = (i0 + half_lat) // lat
    i1 = (i1 + half_lat) // lat
    j0 = (j0 + half_lat) // lat
    j1 = (j1 + half_lat) // lat
    w = i1 - i0 + 1
    h = j1 - j0 + 1
    zbuf = np.empty((h, w), np.float64)
    nv = vertices.shape[0]
    sx = np.empty(nv)
    sy = np.empty(nv)
    iz = np.empty(nv)
    for jj in range(particles.shape[0]):
        p = particles[jj]
        if jj > 0 and same_pose(R, t, obj, particles[jj - 1], p):  # a copy left by a resampling: same depths
            copy_depth_row(particles[jj - 1], p, obj, subset, out, loc, dirty)
            continue
        Rm = R[p, obj]
        zbuf[:, :] = np.inf
        for a in range(nv):
            X = Rm[0, 0] * vertices[a, 0] + Rm[0, 1] * vertices[a, 1] + Rm[0, 2] * vertices[a, 2] + t[p, obj, 0]
            Y = Rm[1, 0] * vertices[a, 0] + Rm[1, 1] * vertices[a, 1] + Rm[1, 2] * vertices[a, 2] + t[p, obj, 1]
            Z = Rm[2, 0] * vertices[a, 0] + Rm[2, 1] * vertices[a, 1] + Rm[2, 2] * vertices[a, 2] + t[p, obj, 2]
            if Z < 1e-3:
                Z = 1e-3
            # grid coordinates
            sx[a] = ((fx * X / Z + cx) - off) / (f * lat)
            sy[a] = ((fy * Y / Z + cy) - off) / (f * lat)
            iz[a] = 1.0 / Z
        for fi in range(faces.shape[0]):
            a = faces[fi, 0]
            b = faces[fi, 1]
            c = faces[fi, 2]
            x0, y0, x1, y1, x2, y2 = sx[a], sy[a], sx[b], sy[b], sx[c], sy[c]
            area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
            if abs(area) < 1e-12:
                continue
            cmin = max(int(np.ceil(min(x0, min(x1, x2)))), i0)
            cmax = min(int(np.floor(max(x0, max(x1, x2)))), i1)
            rmin = max(int(np.ceil(min(y0, min(y1, y2)))), j0)
            rmax = min(int(np.floor(max(y0, max(y1, y2)))), j1)
            if cmin > cmax or rmin > rmax:
                continue
            inv_area = 1.0 / area
            for r in range(rmin, rmax + 1):
                for col in range(cmin, cmax + 1):
                    w0 = ((x1 - col) * (y2 - r) - (x2 - col) * (y1 - r)) * inv_area
                    w1 = ((x2 - col) * (y0 - r) - (x0 - col) * (y2 - r)) * inv_area
                    w2 = 1.0 - w0 - w1
                    if w0 < -1e-9 or w1 < -1e-9 or w2 < -1e-9:
                        continue
                    izp = w0 * iz[a] + w1 * iz[b] + w2 * iz[c]
                    if izp <= 0.0:
                        continue
                    z = 1.0 / izp
                    if z < zbuf[r - j0, col - i0]:
                        zbuf[r - j0, col - i0] = z
        for ii in range(subset.shape[0]):
            i = subset[ii]
            col = loc[obj, i]
            if col < 0:
                continue
            d = zbuf[(gj[i] + half_lat) // lat - j0, (gi[i] + half_lat) // lat - i0]
            if out[p, col] != d:
                out[p, col] = d
                dirty[p, i] = 1
