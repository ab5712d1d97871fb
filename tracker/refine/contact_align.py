"""Contact alignment (not in the seed; ``contact_align_deg``, 20° in the default preset): a resting box part in face
contact with a better-seen resting box part has its faces parallel to that part's.

Parts connected in an assembly touch face to face with parallel faces. When one of them is half hidden by the
other (a cube with another stacked on it or set against it), the dense refinement sees only one or two of its faces
and can settle 5–15° off about the axis those faces leave free, while its neighbour, fully seen, is placed within a
degree. After the refinement such a part is turned about its centre onto the nearest rotation whose axes are
parallel to its neighbour's (one of the 24 turns of the cube group), when that turn is small. Camera frame, metres.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from tracker.filter.camera_motion import move_part
from tracker.geometry.symmetry import cube_group

if TYPE_CHECKING:
    from tracker.filter.particle_filter import MultiObjectTracker, TrackerState

CONTACT_TOLERANCE_M = 0.006
"""Metres: a part's centre lies this close to the distance at which its box touches a face of its neighbour's."""
SUPPORT_RATIO = 1.5
"""The neighbour must have at least this many times the part's matched depth points in this frame's refinement."""

_GROUP = cube_group()


def face_contact(R_a: np.ndarray, c_a: np.ndarray, half_a: np.ndarray, R_b: np.ndarray, c_b: np.ndarray,
                 half_b: np.ndarray, tol: float = CONTACT_TOLERANCE_M) -> bool:
    """Do boxes a and b (rotations body → camera, centres (m, camera frame), half sizes (m)) touch face to face:
    along one of b's axes a's centre lies within ``tol`` of the distance at which the two boxes touch, and across it
    their extents overlap?"""
    rel = R_b.T @ R_a  # a's axes in b's frame
    d = R_b.T @ (c_a - c_b)  # a's centre in b's frame
    ext_a = np.abs(rel) @ half_a  # a's half extent along each of b's axes
    reach = half_b + ext_a
    for ax in range(3):
        others = [o for o in range(3) if o != ax]
        if abs(abs(d[ax]) - reach[ax]) <= tol and all(abs(d[o]) < reach[o] for o in others):
            return True
    return False


def nearest_parallel(R_a: np.ndarray, R_b: np.ndarray) -> tuple[np.ndarray, float]:
    """The rotation nearest to ``R_a`` whose axes are parallel to ``R_b``'s (``R_b S`` over the cube group), and the
    angle (rad) between the two."""
    cands = np.einsum("ij,njk->nik", R_b, _GROUP)
    cos = (np.einsum("ij,nij->n", R_a, cands) - 1.0) / 2.0  # trace(R_aᵀ C) = Σ R_a ∘ C
    best = int(np.argmax(cos))
    return cands[best], float(np.arccos(np.clip(cos[best], -1.0, 1.0)))


def resting(trk: MultiObjectTracker, moved: np.ndarray) -> np.ndarray:
    """(K,) bool: box parts that are neither carried nor moving with their blob and whose estimate travelled less
    than ``carry_min_motion`` in the carry test's window (``moved``, m)."""
    k = len(trk.parts)
    out = np.zeros(k, bool)
    for i in range(k):
        out[i] = (trk.meshes[i] is None and not trk._carry.carried[i] and not trk._blob_moved[i]
                  and moved[i] <= trk.config.carry_min_motion)
    return out


def support(trk: MultiObjectTracker) -> np.ndarray:
    """(K,) matched depth points of each part in this frame's refinement (0 without one; -1 when not healthy, so
    that such a part is never a reference)."""
    out = np.zeros(len(trk.parts))
    last = trk._refiner.last if trk._refiner is not None else [None] * len(trk.parts)
    for i, res in enumerate(last):
        if res is not None:
            out[i] = res.n_valid if res.healthy else -1.0
    return out


def align_contacts(trk: MultiObjectTracker, state: TrackerState) -> list[str]:
    """``contact_align_deg``: turn every resting box part refined this frame that is in face contact with a resting,
    healthily refined box part with ``SUPPORT_RATIO`` times its matched depth points onto the nearest rotation
    parallel to that neighbour's, about its centre, when the turn is smaller than ``contact_align_deg`` (the best
    supported such neighbour is used; parts are taken one by one, from the least supported, each once, and an aligned
    part is compared at its new pose by the parts after it). ``state.poses`` / ``state.particles`` get the new
    estimates. Returns the names of the parts turned."""
    max_turn = np.radians(trk.config.contact_align_deg)
    if max_turn <= 0 or trk._refiner is None:
        return []
    rest = resting(trk, trk._carry.moved())
    n = support(trk)
    poses = [trk.estimates[nm] for nm in trk.names]
    centres = [p.R @ trk.center[i] + p.t for i, p in enumerate(poses)]
    turned: list[str] = []
    for a in np.argsort(n, kind="stable"):  # the least supported first
        if not rest[a] or n[a] < 0 or trk._refiner.last[a] is None:
            continue
        refs = [b for b in range(len(trk.parts)) if b != a and rest[b] and n[b] >= SUPPORT_RATIO * max(n[a], 1.0)
                and face_contact(poses[a].R, centres[a], trk.half[a], poses[b].R, centres[b], trk.half[b])]
        if not refs:
            continue
        b = max(refs, key=lambda o: n[o])
        R_new, angle = nearest_parallel(poses[a].R, poses[b].R)
        if angle < 1e-6 or angle > max_turn:
            continue
        Q = R_new @ poses[a].R.T
        move_part(trk, int(a), Q, centres[a] - Q @ centres[a])
        name = trk.names[a]
        state.poses[name] = trk.estimates[name]
        state.particles[name] = trk.p[:, a].astype(np.float32)
        poses[a] = trk.estimates[name]
        turned.append(name)
    return turned
