"""Loss detection and re-acquisition of a part's pose from the depth data (spec ``depth-refinement.md``, "Health
and loss").

:class:`LossMonitor` keeps, per part, how many frames in a row the dense-depth refinement could not support the
estimate although the part should be visible (its colour blob is there, or the filter believes it visible). A part
is *lost* after ``bad_frames`` such frames, and is *re-checked* in any case right after a hand releases it or when it
reappears after being hidden. :func:`reacquire` then runs the refinement from several starting rotations about the
part's centre (a fixed, deterministic set of axes on a Fibonacci sphere and angles: for a cube the largest useful
angle is about 60°, beyond which a symmetric copy is nearer, plus turns about the table normal, the way a part put
down on the table differs from its estimate; for a mesh the whole of SO(3) up to 180°) and keeps the start whose
refined pose the depth supports best (:attr:`RefineResult.score`: matched model points minus twice
the free-space violations). It replaces the estimate only when that support clearly beats the current pose's.
Camera frame, metres, radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from tracker.refine.dense_depth import RefineResult
from tracker.refine.part_refiner import PartRefiner


def fibonacci_axes(n: int) -> np.ndarray:
    """``n`` unit vectors spread evenly on the sphere (deterministic)."""
    i = np.arange(n) + 0.5
    phi = np.arccos(1.0 - 2.0 * i / n)
    theta = np.pi * (1.0 + 5.0**0.5) * i
    return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], axis=1)


def start_rotations(angles_deg: tuple[float, ...], n_axes: int) -> np.ndarray:
    """Rotation matrices (M, 3, 3): identity plus each angle about each of ``n_axes`` Fibonacci axes."""
    mats = [np.eye(3)]
    axes = fibonacci_axes(n_axes)
    for a in angles_deg:
        mats.extend(Rotation.from_rotvec(axes * np.radians(a)).as_matrix())
    return np.asarray(mats)


CUBE_STARTS = start_rotations((25.0, 50.0), 12)
"""Starts for a part with the cube's symmetry (25 rotations)."""
CUBE_TURNS_DEG = (-40.0, -20.0, 20.0, 40.0)
"""Turns about the table normal tried in addition for a cube (its symmetry repeats every 90° about it)."""


def turns_about(axis: np.ndarray, angles_deg: tuple[float, ...]) -> np.ndarray:
    """Rotation matrices (M, 3, 3) by each angle about the unit ``axis`` (camera frame)."""
    a = np.asarray(axis, np.float64)
    a = a / np.linalg.norm(a)
    return Rotation.from_rotvec(np.radians(np.asarray(angles_deg))[:, None] * a[None]).as_matrix()


MESH_STARTS = start_rotations((30.0, 60.0, 90.0, 135.0, 180.0), 14)
"""Starts for a part without symmetry (71 rotations)."""


@dataclass
class PartHealth:
    """Per-part loss bookkeeping."""

    bad: int = 0
    hidden: bool = False


class LossMonitor:
    """Decides per part and frame whether to re-acquire (see module docstring)."""

    def __init__(self, n_parts: int, bad_frames: int = 3) -> None:
        self.health = [PartHealth() for _ in range(n_parts)]
        self.bad_frames = int(bad_frames)

    def update(self, obj: int, result: RefineResult | None, should_be_visible: bool, released: bool) -> bool:
        """Record this frame's refinement of part ``obj`` (None: not refined); True when it must be re-acquired."""
        h = self.health[obj]
        if not should_be_visible:
            h.hidden, h.bad = True, 0
            return False
        reappeared = h.hidden
        h.hidden = False
        supported = result is not None and result.healthy
        h.bad = 0 if supported else h.bad + 1
        return released or reappeared or h.bad >= self.bad_frames

    def reset(self, obj: int) -> None:
        self.health[obj] = PartHealth()


def tilt_from(R: np.ndarray, up: np.ndarray) -> float:
    """Degrees between the unit vector ``up`` (camera frame) and the nearest of the box axes ``±R[:, k]``
    (``R``: part-to-camera rotation): 0 for a box lying flat on one of its faces on a plane with normal ``up``."""
    cosines = np.abs(np.asarray(R, np.float64).T @ np.asarray(up, np.float64))
    return float(np.degrees(np.arccos(np.clip(np.max(cosines), 0.0, 1.0))))


def reacquire(refiner: PartRefiner, depth: np.ndarray, obj: int, R: np.ndarray, t: np.ndarray,
              allowed: np.ndarray | None, starts: np.ndarray, current: RefineResult | None = None,
              outline: np.ndarray | None = None, frame_depth: np.ndarray | None = None,
              margin: float = 10.0, up: np.ndarray | None = None, tilt_gain: float = 0.0,
              tilt_deg: float = 15.0) -> RefineResult | None:
    """Best-supported refinement of part ``obj`` over the starting rotations ``starts`` (about its centre, applied
    to ``(R, t)``; ``outline``: the blob's polygon for the silhouette term, ``frame_depth`` the depth on which it
    tests occlusion): the refinement from ``(R, t)`` itself (``current`` when the caller has it already) unless
    another start's score beats it by ``margin``; None when no start gives a healthy refinement.

    ``up`` (unit table normal, camera frame, for a box part) with ``tilt_gain`` > 0: a candidate whose refined
    rotation is tilted more than ``tilt_deg`` off lying flat on the table (:func:`tilt_from`) must also beat the
    best candidate within ``tilt_deg`` of flat (the estimate's own refinement included) by ``tilt_gain`` × that
    one's score plus ``margin``. A sliver of a mostly hidden cube fits a tilted face a few points better than the
    right flat pose; a start that puts a cube tilted by a carry flat again is judged by the plain margin."""
    R = np.asarray(R, np.float64)
    t = np.asarray(t, np.float64)
    c = R @ refiner.centers[obj] + t
    if current is None:
        current = refiner.refine_one(depth, obj, R, t, allowed, outline, frame_depth)
    found: list[RefineResult] = []
    for S in starts[1:]:
        Rs = S @ R
        ts = c - Rs @ refiner.centers[obj]
        res = refiner.refine_one(depth, obj, Rs, ts, allowed, outline, frame_depth)
        if res.healthy and not res.position_only:
            found.append(res)
    judge_tilt = up is not None and tilt_gain > 0.0
    tilted = [judge_tilt and tilt_from(res.R, up) > tilt_deg for res in found]
    flat_scores = [res.score for res, tl in zip(found, tilted, strict=True) if not tl]
    if judge_tilt and current.healthy and tilt_from(current.R, up) <= tilt_deg:
        flat_scores.append(current.score)
    tilt_bar = max(flat_scores, default=-np.inf) * (1.0 + tilt_gain) + margin
    best, best_score = (current, current.score) if current.healthy else (None, -np.inf)
    for res, tl in zip(found, tilted, strict=True):  # in start order (keeps the turned start)
        if res.score > best_score + margin and (not tl or res.score > tilt_bar):
            best, best_score = res, res.score
    return best
