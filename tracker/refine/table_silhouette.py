"""Table-silhouette stage (not in the seed; an addition of the tracker): a part resting on the table that the colour
camera sees but the depth camera does not is placed from the outline of its colour blob.

A structured-light sensor has no depth where its projector cannot reach: in the projector shadow of a hand held
over the table, a part can be fully in view of the colour camera and have almost no depth pixels. The depth
likelihood and the dense refinement then have nothing to go on, the filter takes the part for hidden, and the part
is held by the priors or moved with the scene's motion, so it drifts by several millimetres (more when the camera
moves). Colour still shows it, and a part resting on the table has only three free coordinates: its position along
the table and its turn about the table's normal. Those three are well fixed by the blob's outline.

Per part and frame, when

* the part is a coloured box, not carried, not moving with its blob and its dense refinement gave no correction;
* its estimate rests on the table (lowest corner within ``table_silhouette_max_height`` of the plane, one face
  within ``table_silhouette_max_tilt_deg`` of lying flat);
* it has a confident blob with an outline;

the silhouette residuals of :mod:`tracker.refine.region_term` (rendered outline against the blob's signed distance,
outline points hidden by something in front dropped) are minimised over the planar twist ``ξ = B q`` with
``q = (θ, a, b)``: a turn θ about the table normal ``n`` through the part's centre and a shift ``a e₁ + b e₂`` along
the table (``e₁ ⟂ n``, ``e₂ = n × e₁``). Gauss-Newton on ``(Bᵀ H B + Λ) q = −Bᵀ g`` with ``H``, ``g`` the term's
normal equations. A blob smaller than ``table_silhouette_turn_coverage`` of the part's whole silhouette (a sliver
beside a hand) fixes the shift but hardly the turn: the part is then only shifted (always without
``table_silhouette_turn``). The part's tilt is not changed;
with ``table_silhouette_snap`` it is first moved along the normal onto the table (its lowest corner on the plane:
the outline of a part floating a millimetre above the table would otherwise be matched by shifting it along the
table).

The result is taken only when it explains the blob: the share of the blob inside the part's expected visible
silhouette (rendered at full resolution with every part, minus pixels whose measured depth is in front of it,
eroded like the blob) and the intersection over union of the two must reach ``table_silhouette_min_iou`` and must
not get worse than at the starting pose (by more than 0.02: pixel rounding), and the move must stay within
``table_silhouette_max_step`` / ``table_silhouette_max_turn_deg``. The fit is then the part's correction, as a
healthy dense refinement's would be (:mod:`tracker.refine.refine_stage`: the particles move with it; the part is
not re-acquired from the depth, whose sliver would explain a tilted pose as well, and it does not follow the
scene's motion this frame).

Camera frame, metres, radians; pixels are full-resolution image coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from tracker.filter.colour_input import blob_mask, confident
from tracker.filter.hidden_parts import lowest_height
from tracker.filter.motion_model import rotvec_to_matrix
from tracker.geometry.camera import Intrinsics
from tracker.refine.dense_depth import RefineResult
from tracker.refine.region_term import RegionTerm
from tracker.refine.surface_render import render_surfaces

if TYPE_CHECKING:
    from tracker.filter.particle_filter import MultiObjectTracker

_ERODE = np.ones((5, 5), np.uint8)
"""The blob masks are eroded by 2 px (:func:`tracker.filter.colour_input.make_blob_mask`); so is the expected
silhouette before the two are compared."""


@dataclass
class SilhouetteFit:
    """Outcome of :func:`fit_part` (the fit and its check): ``R``, ``t`` the fitted pose (body → camera); ``iou`` and
    ``inside`` (share of the blob inside the expected silhouette) at the fitted pose, ``iou0`` at the start."""

    R: np.ndarray
    t: np.ndarray
    iou: float
    inside: float
    iou0: float
    accepted: bool
    reason: str = ""


def planar_basis(up: np.ndarray) -> np.ndarray:
    """(6, 3) matrix ``B`` mapping ``(θ, a, b)`` to the twist ``(ω, v)``: a turn θ about the unit normal ``up`` and a
    shift ``a e₁ + b e₂`` in the plane (``e₁``, ``e₂`` orthonormal, perpendicular to ``up``)."""
    n = np.asarray(up, np.float64) / np.linalg.norm(up)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    B = np.zeros((6, 3))
    B[:3, 0] = n
    B[3:, 1] = e1
    B[3:, 2] = e2
    return B


def fit_on_table(term: RegionTerm, R0: np.ndarray, t0: np.ndarray, center: np.ndarray, up: np.ndarray,
                 depth: np.ndarray, intrinsics: Intrinsics, iterations: int = 8, lambda_rot: float = 25.0,
                 lambda_trans: float = 2500.0, min_points: int = 12,
                 turn: bool = True) -> tuple[np.ndarray, np.ndarray, int]:
    """Minimise the silhouette ``term``'s residuals over the planar twists about the part's centre (``center``, body
    frame) from the pose ``(R0, t0)`` (shifts only when ``turn`` is False). Returns the pose and the number of
    outline points paired at the last update (0 when an update had fewer than ``min_points``; the pose is then the
    start)."""
    B = planar_basis(up)
    prior = np.diag([lambda_rot, lambda_trans, lambda_trans])
    if not turn:
        B, prior = B[:, 1:], prior[1:, 1:]
    R = np.array(R0, np.float64)
    t = np.array(t0, np.float64)
    n = 0
    for _ in range(iterations):
        c = R @ center + t
        H, g, n = term.normal_equations(R, t, c, depth, intrinsics)
        if n < min_points:
            return np.array(R0, np.float64), np.array(t0, np.float64), 0
        H = np.triu(H) + np.triu(H, 1).T  # the kernels fill the upper triangle
        q = -np.linalg.solve(B.T @ H @ B + prior, B.T @ g)
        xi = B @ q
        Rw = rotvec_to_matrix(xi[:3])[0]
        t = c + Rw @ (t - c) + xi[3:]
        R = Rw @ R
        if np.linalg.norm(q) < 1e-7:
            break
    return R, t, n


def _render_window(trk: MultiObjectTracker, obj: int, poses: list, pad: int):
    """Full-resolution render of the parts at ``poses`` over part ``obj``'s image rectangle widened by ``pad`` px
    (clipped to the image): ``(render, (u0, v0, u1, v1))``, or None when the part does not project."""
    own = [None] * len(poses)
    own[obj] = poses[obj]
    rect = trk._refiner._rect(own)
    if rect is None:
        return None
    intr = trk.intrinsics
    u0, v0, u1, v1 = rect
    rect = (max(u0 - pad, 0), max(v0 - pad, 0), min(u1 + pad, intr.width), min(v1 + pad, intr.height))
    return render_surfaces(intr, trk._refiner.shapes, poses, rect, 1), rect


def silhouette_agreement(trk: MultiObjectTracker, obj: int, poses: list, blob: np.ndarray, frame_depth: np.ndarray,
                         occlusion_m: float) -> tuple[float, float]:
    """``(iou, inside)`` of part ``obj``'s expected visible silhouette at ``poses[obj]`` (every part rendered at
    ``poses``, full resolution; pixels whose measured depth lies more than ``occlusion_m`` in front of the part are
    not expected in the blob) and its ``blob`` mask (H×W); ``inside``: share of the blob's pixels in the
    silhouette. Both 0 when the part does not project."""
    found = _render_window(trk, obj, poses, pad=6)
    if found is None:
        return 0.0, 0.0
    render, (u0, v0, u1, v1) = found
    sil = render.label == obj
    meas = frame_depth[v0:v1, u0:u1]
    with np.errstate(invalid="ignore"):
        hidden = np.isfinite(meas) & (meas > 0) & (meas < render.depth - occlusion_m)
    expected = cv2.erode((sil & ~hidden).astype(np.uint8), _ERODE).astype(bool)
    b = blob[v0:v1, u0:u1]
    total = int(np.count_nonzero(blob))
    if total == 0:
        return 0.0, 0.0
    inter = int(np.count_nonzero(expected & b))
    union = int(np.count_nonzero(expected | b)) + (total - int(np.count_nonzero(b)))
    return inter / max(union, 1), inter / total


def silhouette_area(trk: MultiObjectTracker, obj: int, pose: tuple[np.ndarray, np.ndarray]) -> int:
    """Pixels of part ``obj``'s whole silhouette at ``pose`` (rendered alone, eroded like a blob)."""
    own = [None] * len(trk.parts)
    own[obj] = pose
    found = _render_window(trk, obj, own, pad=0)
    if found is None:
        return 0
    return int(np.count_nonzero(cv2.erode((found[0].label == obj).astype(np.uint8), _ERODE)))


def resting(trk: MultiObjectTracker, obj: int, R: np.ndarray, t: np.ndarray, plane) -> bool:
    """Does part ``obj`` at ``(R, t)`` rest on the table ``plane = (n, d)`` (lowest corner within
    ``table_silhouette_max_height``, a face within ``table_silhouette_max_tilt_deg`` of lying flat)?"""
    cfg = trk.config
    if abs(lowest_height(trk, obj, R, t, plane)) > cfg.table_silhouette_max_height:
        return False
    flat = float(np.abs(R.T @ plane[0]).max())
    return flat >= np.cos(np.radians(cfg.table_silhouette_max_tilt_deg))


def place_on_table(trk: MultiObjectTracker, poses: list, corrections: list, detections, plane,
                   frame_depth: np.ndarray | None, held: np.ndarray | None = None) -> np.ndarray:
    """The stage (module docstring), inside the refinement: for every part without a depth correction
    (``corrections[k]`` None) that qualifies, fit it on the table from its estimate ``poses[k] = (R, t)``; an accepted
    fit becomes its correction (``corrections`` is updated). ``held[k]``: part k was not refined this frame on
    purpose (``quiet_refine_skip``) and is not fitted either. Returns the bool mask of the parts placed; the fits are
    kept in ``trk.last_silhouette`` (diagnostics)."""
    cfg = trk.config
    k = len(trk.parts)
    placed = np.zeros(k, bool)
    trk.last_silhouette = [None] * k
    if (not cfg.table_silhouette or plane is None or frame_depth is None or not detections or trk._refiner is None
            or trk._refiner.region is None):
        return placed
    carried = np.asarray(trk._carry.carried, bool)
    for i, name in enumerate(trk.names):
        part = trk.parts[i]
        if (corrections[i] is not None or part.box is None or part.color is None or carried[i] or trk._blob_moved[i]
                or (held is not None and held[i])):
            continue
        det = detections.get(name)
        if det is None or getattr(det, "contour", None) is None:
            continue
        if not confident(trk, float(getattr(det, "score", 0.0) or 0.0), getattr(det, "area", None)):
            continue
        R0, t0 = (np.asarray(a, np.float64) for a in poses[i])
        if not resting(trk, i, R0, t0, plane):
            continue
        blob = blob_mask(trk, det, frame_depth.shape)
        if blob is None:
            continue
        fit = fit_part(trk, i, poses, blob, det.contour, plane, frame_depth)
        trk.last_silhouette[i] = fit
        if fit is None or not fit.accepted:
            continue
        res = RefineResult(fit.R, fit.t, True, 0, 0, 0.0, float("nan"), reason="placed by the table silhouette")
        corrections[i] = trk._refiner.correction(R0, t0, res)
        placed[i] = True
    return placed


def fit_part(trk: MultiObjectTracker, obj: int, poses: list, blob: np.ndarray, contour: np.ndarray,
             plane: tuple[np.ndarray, float], frame_depth: np.ndarray) -> SilhouetteFit | None:
    """Fit part ``obj`` on the table ``plane = (n, d)`` to its blob (``blob`` mask, ``contour`` polygon) from
    ``poses[obj]`` (the other parts at ``poses`` as well) and check the fit (module docstring); None when no
    silhouette term can be made."""
    cfg = trk.config
    up = np.asarray(plane[0], np.float64)
    ref = trk._refiner
    poses = list(poses)
    R0, t0 = (np.asarray(a, np.float64) for a in poses[obj])
    term = ref._region(poses, obj, contour, frame_depth)
    if term is None:
        return None
    ts = t0 - up * lowest_height(trk, obj, R0, t0, plane) if cfg.table_silhouette_snap else t0
    turn = cfg.table_silhouette_turn and (
        cfg.table_silhouette_turn_coverage <= 0.0
        or np.count_nonzero(blob) >= cfg.table_silhouette_turn_coverage * silhouette_area(trk, obj, (R0, ts)))
    R, t, n = fit_on_table(term, R0, ts, trk.center[obj], up, frame_depth, trk.intrinsics,
                           cfg.table_silhouette_iterations, turn=turn)
    if n == 0:
        return SilhouetteFit(R0, t0, 0.0, 0.0, 0.0, False, "too few outline points paired")
    occl = ref.region.occlusion_m
    iou0, _ = silhouette_agreement(trk, obj, poses, blob, frame_depth, occl)
    poses[obj] = (R, t)
    iou, inside = silhouette_agreement(trk, obj, poses, blob, frame_depth, occl)
    c0 = R0 @ trk.center[obj] + t0
    c1 = R @ trk.center[obj] + t
    turn = float(np.arccos(np.clip((np.trace(R @ R0.T) - 1.0) / 2.0, -1.0, 1.0)))
    fit = SilhouetteFit(R, t, iou, inside, iou0, False)
    if iou < cfg.table_silhouette_min_iou or inside < cfg.table_silhouette_min_iou:
        fit.reason = "the fitted silhouette does not explain the blob"
    elif iou < iou0 - 0.02:
        fit.reason = "the fit explains the blob worse than the estimate"
    elif np.linalg.norm(c1 - c0) > cfg.table_silhouette_max_step or turn > np.radians(
            cfg.table_silhouette_max_turn_deg):
        fit.reason = "the fit moves the part too far"
    else:
        fit.accepted = True
    return fit
