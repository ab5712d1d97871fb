"""Rotational symmetry groups of parts and symmetry-aware orientation errors.

* A cube has the 24-element rotation group of the cube (spec section 8.1), generated with
  ``scipy.spatial.transform.Rotation.create_group("O")``.
* A box with two equal edges has the 8 rotations that map the box onto itself; a box with three
  distinct edges has 4 (identity and the 180° turns about its axes).
* A mesh part is treated as having no symmetry.

Matrices act on body-frame coordinates: a symmetry ``S`` satisfies ``S · part = part``, so the
orientations ``R`` and ``R @ S`` of a part are indistinguishable.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.spatial.transform import Rotation

from tracker.geometry.parts import PartSpec


@lru_cache(maxsize=1)
def cube_group() -> np.ndarray:
    """The 24 rotation matrices ``[24, 3, 3]`` of the cube group; element 0 is the identity."""
    mats = Rotation.create_group("O").as_matrix()
    mats = np.rint(mats)  # entries are exactly 0 or ±1
    order = np.argsort([0 if np.allclose(m, np.eye(3)) else 1 for m in mats], kind="stable")
    return mats[order]


def box_group(size: tuple[float, float, float], tol: float = 1e-6) -> np.ndarray:
    """Rotations ``[M, 3, 3]`` that map an axis-aligned box of edge lengths ``size`` (metres) onto itself."""
    size = np.asarray(size, dtype=float)
    keep = []
    for S in cube_group():
        # S permutes (and flips) axes; the box maps onto itself when the permuted extents match.
        if np.allclose(np.abs(S) @ size, size, atol=tol):
            keep.append(S)
    return np.asarray(keep)


def symmetry_group(part: PartSpec) -> np.ndarray:
    """Symmetry rotations of a part (identity only for meshes)."""
    if part.box is not None:
        return box_group(part.box)
    return np.eye(3)[None]


def symmetric_rotation_error(R_est: np.ndarray, R_true: np.ndarray, group: np.ndarray) -> float:
    """Smallest angle (radians) between ``R_est`` and ``R_true @ S`` over the symmetries ``S`` in ``group``."""
    cands = np.einsum("ij,njk->nik", R_true, group)
    rel = np.einsum("ji,njk->nik", R_est, cands)  # R_estᵀ · R_true · S
    cos = (np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0
    return float(np.arccos(np.clip(cos.max(), -1.0, 1.0)))


def nearest_in_group(R: np.ndarray, group: np.ndarray | None = None) -> tuple[int, np.ndarray]:
    """Index and matrix of the group element closest (in rotation angle) to ``R`` (default group: cube)."""
    g = cube_group() if group is None else group
    score = np.einsum("ij,nij->n", R, g)  # trace(Rᵀ S) grows as the angle shrinks
    i = int(np.argmax(score))
    return i, g[i]
