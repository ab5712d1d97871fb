"""Hidden-parts stage: parts the depth camera cannot see are held by a hand (hand carry,
:mod:`tracker.filter.hand_carry`), at rest (rest prior) or on the table (support prior). None of this is in the
seed; each piece is a :class:`~tracker.filter.tracker_config.TrackerConfig` setting. Camera frame, metres.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from tracker.filter.hand_carry import supported_by_other
from tracker.filter.predict import adaptive_noise
from tracker.geometry.pose import Pose

if TYPE_CHECKING:
    from tracker.filter.frame_context import FrameContext
    from tracker.filter.particle_filter import MultiObjectTracker


def hold_hidden_parts(trk: MultiObjectTracker, ctx: FrameContext, detections, detected: np.ndarray) -> np.ndarray:
    """Move carried parts with the hand, switch the rest prior on for hidden resting parts; returns each part's
    motion-noise scale (K,) for this frame."""
    cfg = trk.config
    k = len(trk.parts)
    if cfg.carry_follow:
        follow_hands(trk, ctx.depth, detected, ctx.table_plane, detections, ctx.touched)
    noise_scale = trk._noise_scale * adaptive_noise(trk)
    trk._rest_on = np.zeros(k, bool)
    if cfg.rest_prior_sigma > 0 and cfg.use_color_input and detections is not None:
        # little depth evidence (hidden, or in the sensor's shadow next to a hand) and no sign of motion
        trk._rest_on = trk.visibility < cfg.rest_prior_max_visibility
        for i in np.nonzero(trk._rest_on)[0]:
            if blob_left_rest(trk, i, detections.get(trk.names[i])):
                trk._rest_on[i] = False  # a sliver of the part shows where it was not: it is moving
        if trk._rest_on.any():
            trk.v[:, trk._rest_on] = 0.0
    if cfg.detected_full_noise:
        noise_scale[detected] = 1.0
    return noise_scale


def follow_hands(trk, depth, detected: np.ndarray, plane, detections, touched: frozenset[str] = frozenset()) -> None:
    """Hand carry (:mod:`tracker.filter.hand_carry`): shift hidden carried parts with the hand that holds them
    (``plane``: the table's (normal, offset) or None; ``touched``: parts a tracked hand touches). A carried part
    whose reliable colour blob stays put while the hand moves on has been let go: released."""
    cfg = trk.config
    k = len(trk.parts)
    pos = np.array([trk.estimates[nm].t for nm in trk.names])
    heights = np.full(k, np.inf)
    if plane is not None:
        for i, nm in enumerate(trk.names):
            heights[i] = lowest_height(trk, i, trk.estimates[nm].R, pos[i], plane)
    hidden = trk.visibility < cfg.rest_prior_max_visibility  # little depth evidence (previous frame)
    rot, delta = trk._carry.update(depth, pos, hidden, ~hidden, heights, plane,
                                   np.array([nm in touched for nm in trk.names], bool))
    centers = {}
    for i, nm in enumerate(trk.names):
        det = detections.get(nm) if detections else None
        c = getattr(det, "center", None) if det is not None else None
        if c is not None and detected[i]:
            centers[i] = np.asarray(c, np.float64)
    moving = (np.abs(delta).sum(1) > 0) | (np.abs(rot - np.eye(3)).sum((1, 2)) > 0)
    for i in np.nonzero(moving)[0]:
        nm = trk.names[i]
        new_pos = rot[i] @ pos[i] + delta[i]
        if i in centers and i in trk._last_centers:
            uv = trk.intrinsics.project(np.array([pos[i], new_pos]))
            hand_px = float(np.linalg.norm(uv[1] - uv[0]))
            blob_px = float(np.linalg.norm(centers[i] - trk._last_centers[i]))
            if hand_px > 3.0 and blob_px < 0.3 * hand_px:
                trk._carry.release(i)
                continue
        trk.p[:, i] = trk.p[:, i] @ rot[i].T + delta[i]
        trk.R[:, i] = np.einsum("ij,njk->nik", rot[i], trk.R[:, i])
        trk.v[:, i] = 0.0
        est = trk.estimates[nm]
        trk.estimates[nm] = Pose.from_rt(rot[i] @ est.R, rot[i] @ est.t + delta[i])
        trk._rest_t[i] = rot[i] @ trk._rest_t[i] + delta[i]
    trk._last_centers = centers
    update_support(trk, hidden & ~trk._carry.carried, pos, heights, plane)


def update_support(trk, unseen: np.ndarray, pos: np.ndarray, heights: np.ndarray, plane) -> None:
    """Which parts get the support prior: ``unseen`` (little depth evidence, not carried) and not on another
    part. Their rest anchors, when in the air (last seen in a hand), are set down on the table too."""
    k = len(trk.parts)
    trk._support_on = np.zeros(k, bool)
    if plane is None or trk.config.support_prior_sigma <= 0:
        return
    for i in np.nonzero(unseen)[0]:
        if supported_by_other(i, pos, heights, trk._carry.radii, margin=0.01):
            continue
        trk._support_on[i] = True
        h = lowest_height(trk, i, trk.estimates[trk.names[i]].R, trk._rest_t[i], plane)
        if h > trk.config.carry_min_height:
            trk._rest_t[i] = trk._rest_t[i] - h * plane[0]


def lowest_height(trk, obj: int, R: np.ndarray, t: np.ndarray, plane) -> float:
    """Height (m) above the table plane ``(n, d)`` of part ``obj``'s lowest vertex at pose (R, t)."""
    n, d = plane
    return float((trk.hulls[obj] @ (R.T @ n)).min() + t @ n + d)


def blob_left_rest(trk, obj: int, det) -> bool:
    """Does the colour blob of part ``obj`` reach more than ``rest_release_px`` beyond the part's projected
    bounding rectangle at its rest anchor? (A resting part partly hidden by a hand shows a blob inside it.)"""
    bbox = getattr(det, "bbox", None) if det is not None else None
    if bbox is None or getattr(det, "center", None) is None or trk.config.rest_release_px <= 0:
        return False
    est = trk.estimates[trk.names[obj]]
    pts = trk.corners[obj] @ est.R.T + trk._rest_t[obj]
    if np.any(pts[:, 2] < 0.01):
        return False
    uv = trk.intrinsics.project(pts)
    x, y, w, h = (float(v) for v in bbox)
    m = trk.config.rest_release_px
    return bool(x < uv[:, 0].min() - m or x + w > uv[:, 0].max() + m or y < uv[:, 1].min() - m
                or y + h > uv[:, 1].max() + m)


def log_support_prior(trk, p, R, plane) -> np.ndarray | float:
    """Support prior (TrackerConfig.support_prior_sigma): the lowest point of an unseen, unheld part that is not
    on another part lies on the table; quadratic within 3σ, linear beyond (it still pulls a floating part)."""
    if plane is None or not trk._support_on.any():
        return 0.0
    sig = trk.config.support_prior_sigma
    out = np.zeros(p.shape[0])
    n, d = plane
    for i in np.nonzero(trk._support_on)[0]:
        nb = np.einsum("nji,j->ni", R[:, i], n)  # Rᵀ n per particle
        h = np.abs((nb @ trk.hulls[i].T).min(axis=1) + p[:, i] @ n + d) / sig
        out -= np.where(h < 3.0, 0.5 * h * h, 3.0 * h - 4.5)
    return out


def log_rest_prior(trk, p) -> np.ndarray | float:
    """Rest prior (TrackerConfig.rest_prior_sigma): Gaussian pull of resting hidden parts to their anchors."""
    if not trk._rest_on.any():
        return 0.0
    sig2 = trk.config.rest_prior_sigma ** 2
    d2 = ((p[:, trk._rest_on] - trk._rest_t[trk._rest_on]) ** 2).sum(-1)
    return -0.5 * np.minimum(d2, 9.0 * sig2).sum(-1) / sig2



def update_rest_anchors(trk: MultiObjectTracker, detected: np.ndarray) -> None:
    """Well-seen parts (reliable blob, visible enough) move their rest-prior anchors to their new estimates."""
    cfg = trk.config
    if cfg.rest_prior_sigma > 0:
        well = detected & (trk.visibility >= cfg.visible_fraction_full)
        for i in np.nonzero(well)[0]:
            trk._rest_t[i] = trk.estimates[trk.names[i]].t
