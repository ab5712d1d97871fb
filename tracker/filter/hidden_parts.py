"""Hidden-parts stage: parts the depth camera cannot see are held by a hand (hand carry,
:mod:`tracker.filter.hand_carry`), at rest (rest prior) or on the table (support prior). None of this is in the
seed; each piece is a :class:`~tracker.filter.tracker_config.TrackerConfig` setting. Camera frame, metres.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numba as nb
import numpy as np

from tracker.filter.blob_follow import centre, footprint, recentre
from tracker.filter.camera_motion import move_part
from tracker.filter.colour_input import box_surface_depth, reseed
from tracker.filter.footprint_depth import (
    _footprint_counts,
    classify_footprint,
    footprint_rect,
    left_place,
)
from tracker.filter.hand_carry import carry_over_sliver, supported_by_other
from tracker.filter.motion_model import rotvec_to_matrix
from tracker.filter.predict import adaptive_noise
from tracker.filter.scene_motion import placed_by_depth
from tracker.geometry.box_renderer import box_depths, pixel_rays
from tracker.geometry.fma import fma
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
        trk._rest_on &= ~trk._blob_moved  # seen to move with its blob (filter/blob_follow.py)
        if cfg.carry_rest_prior and cfg.carry_follow:
            # hidden in a moving hand: held where the hand's motion took it, as a resting part where it was left
            held = trk._carry_moved & (trk.visibility < cfg.rest_prior_max_visibility)
            for i in np.nonzero(held)[0]:
                est = trk.estimates[trk.names[i]]
                trk._rest_t[i], trk._rest_R[i] = est.t.copy(), est.R.copy()
            trk._rest_on |= held
        if trk._rest_on.any():
            trk.v[:, trk._rest_on] = 0.0
            if cfg.rest_prior_rotation:  # the depth cannot turn it; the last good view's rotation holds
                trk.R[:, trk._rest_on] = trk._rest_R[trk._rest_on][None]
    if cfg.detected_full_noise:
        noise_scale[detected] = 1.0
    return noise_scale


def follow_hands(trk, depth, detected: np.ndarray, plane, detections, touched: frozenset[str] = frozenset()) -> None:
    """Hand carry (:mod:`tracker.filter.hand_carry`): shift hidden carried parts with the hand that holds them
    (``plane``: the table's (normal, offset) or None; ``touched``: parts a tracked hand touches). A carried part
    whose confident colour blob stays put while the hand moves on has been let go: released. A carried part whose
    blob shows and keeps its area is put on the image position the blob says (filter/blob_follow.py)."""
    cfg = trk.config
    k = len(trk.parts)
    pos = np.array([trk.estimates[nm].t for nm in trk.names])
    if cfg.carry_over_sliver:  # the hand is registered around where the part was before a re-seed on its sliver
        for i, pre in trk._pre_reseed.items():
            pos[i] = pre.t
    heights = np.full(k, np.inf)
    if plane is not None:
        for i, nm in enumerate(trk.names):
            heights[i] = lowest_height(trk, i, trk.estimates[nm].R, pos[i], plane)
    hidden = trk.visibility < cfg.rest_prior_max_visibility  # little depth evidence (previous frame)
    grasped = np.array([nm in touched for nm in trk.names], bool)
    if cfg.carry_revealed_fraction > 0 and depth is not None:
        for i in np.nonzero(hidden & ~trk._carry.carried & ~detected)[0]:
            # carry_backtrack_rest_m: a part whose estimate has moved since it last rested, a few frames back, is
            # carried from where it rested, moved by the hand's motion since then (the carry's start, HandCarry.update):
            # the shadow counts the hand's motion over the part before it took it, the hand's centroid is not the part
            rest = cfg.carry_backtrack_rest_m > 0 and trk._carry.rest_frame(i) is not None
            if revealed(trk, i, depth):
                if rest:
                    grasped[i] = True
                elif not take_shadow(trk, i, pos):
                    grab(trk, i, depth, pos, plane)
            elif cfg.carry_left_table > 0 and left_place(classify_footprint(trk, i, depth, plane),
                                                         cfg.carry_left_table):
                # the table shows where it was (footprint_depth.py): picked up; carried from now on, moved by the
                # hand's motion since it hid the part (its shadow) or, without one, by this frame's
                grasped[i] = rest or not take_shadow(trk, i, pos, 0.0)
            elif cfg.carry_shadow_take_m > 0:
                take_shadow(trk, i, pos, cfg.carry_shadow_take_m)
    held = hidden | (trk._carry.carried & (trk.visibility < cfg.carry_keep_visibility))  # carry_keep_visibility
    if cfg.carry_keep_unseen > 0 and depth is not None:
        for i in np.nonzero(trk._carry.carried & ~held & ~detected)[0]:
            held[i] = seen_where_it_was(trk, i, depth) < cfg.carry_keep_unseen
    was_carried = trk._carry.carried
    tentative = np.zeros(k, bool)
    if cfg.carry_keep_moving > 0 and depth is not None:
        tentative = was_carried & ~held  # registered with the hand, then kept only if it moved with it (below)
        held = held | tentative
    rotations = np.array([trk.estimates[nm].R for nm in trk.names]) if cfg.carry_backtrack > 0 else None
    rot, delta = trk._carry.update(depth, pos, held, ~held, heights, plane, grasped, rotations)
    for i in np.nonzero(tentative)[0]:
        if not moved_with_hand(trk, i, depth, rot[i], delta[i]):
            trk._carry.release(i)
            rot[i], delta[i] = np.eye(3), np.zeros(3)
    if cfg.carry_anchor_start:
        anchor_at_start(trk, trk._carry.carried & ~was_carried)
    # confident blobs (filter/blob_follow.py), however small: a sliver that stays put while the hand moves on is
    # the part left behind
    centers = {i: b[0] for i, b in enumerate(trk._follow_blobs or []) if b is not None}
    moving = (np.abs(delta).sum(1) > 0) | (np.abs(rot - np.eye(3)).sum((1, 2)) > 0)
    trk._carry_moved = np.zeros(k, bool)
    for i in np.nonzero(moving)[0]:
        nm = trk.names[i]
        new_pos = rot[i] @ pos[i] + delta[i]
        reappeared = centers.get(i) if trk._blob_reappeared[i] else None
        if reappeared is not None and (trk._blob_off[i] or blob_disagrees(trk, i, new_pos, reappeared)):
            # its blob shows up again away from where the hand would take it: the part is not in the hand (any
            # more); it is put where the blob is (the colour stage has done so already for a blob off its silhouette)
            trk._carry.release(i)
            if not trk._blob_off[i]:
                reseed(trk, i, detections.get(nm), depth)
            continue
        if trk._blob_off[i]:
            # the colour stage has just put it on its blob, which shows this frame's motion across the image; with
            # carry_blob_depth the hand's motion gives its depth and turn, with carry_over_sliver the hand's motion
            # takes it unless the blob lies away from where the hand takes it
            det = detections.get(nm)
            if not (cfg.carry_over_sliver and carry_over_sliver(trk, i, rot[i], delta[i], blob_centre(det))) and not (
                    cfg.carry_blob_depth and carry_onto_blob(trk, i, rot[i], delta[i], det)):
                continue
        else:
            put = held_where_put(trk, i, pos[i], new_pos, heights[i], plane)
            if put == "hold":
                continue
            if put == "release" or lifted_off(trk, i, pos[i], new_pos, heights[i], plane):
                trk._carry.release(i)  # the hand rises from a part it has put down: it lets go
                trk._carry.forget(i)  # its motion with the hand is over: the motion test must not take it up again
                continue
            if i in centers and i in trk._last_centers:
                uv = trk.intrinsics.project(np.array([pos[i], new_pos]))
                hand_px = float(np.linalg.norm(uv[1] - uv[0]))
                blob_px = float(np.linalg.norm(centers[i] - trk._last_centers[i]))
                if hand_px > 3.0 and blob_px < 0.3 * hand_px:
                    trk._carry.release(i)
                    continue
            move_part(trk, i, rot[i], delta[i])
        trk._carry_moved[i] = True
        if cfg.table_upright and plane is not None and trk.meshes[i] is None:
            set_down_upright(trk, i, plane, anywhere=cfg.carry_upright_air)
        if cfg.carry_above_table and plane is not None:
            out_of_table(trk, i, plane)
        recentre(trk, i)
    trk._last_centers = centers
    for i in np.nonzero(trk._carry.backtracked & trk._carry.carried & trk._carry_moved)[0]:
        collapse(trk, i)
    # the parts whose carry started this frame and that the hand moved (carry_start_collapse, carry_start_skip)
    trk._carry_started = trk._carry.carried & ~was_carried & trk._carry_moved
    if cfg.carry_start_collapse:
        for i in np.nonzero(trk._carry_started & ~trk._carry.backtracked)[0]:
            collapse(trk, i)
    trk._carry.note_heights(heights, cfg.carry_min_height)
    update_support(trk, hidden & ~trk._carry.carried, pos, heights, plane)


def collapse(trk, obj: int) -> None:
    """Put every particle of part ``obj`` at its estimate (camera frame), velocities zero: a carry started from a
    backtracked pose (``carry_backtrack``) places the part by the hand's motion, and the particles the filter spread
    while it lagged the vanishing part (re-drawn around a sliver's blob, the wide noise of a fast part) would pull
    the estimate, their mean, back off it."""
    est = trk.estimates[trk.names[obj]]
    trk.p[:, obj] = est.t
    trk.R[:, obj] = est.R
    trk.v[:, obj] = 0.0


def moved_with_hand(trk, obj: int, depth: np.ndarray, R: np.ndarray, t: np.ndarray) -> bool:
    """``carry_keep_moving``: carried part ``obj``, visible enough by last frame's estimate to end its carry, stays in
    the hand when this frame's hand motion (x ↦ ``R`` x + ``t``, camera frame, m) moves its centre by at least
    ``carry_keep_moving`` m and this frame's depth shows it better where that motion takes it than where it was
    (:func:`seen_where_it_was` at both poses): a cube 35 % seen in a hand moving it 1 cm a frame is still in the hand;
    a cube the hand has let go stays where the depth shows it. With ``carry_keep_moving_pre_reseed`` a part re-seeded
    on its blob this frame is moved from its pose before the re-seed (:func:`moved_from`)."""
    est = moved_from(trk, obj)
    moved = Pose.from_rt(R @ est.R, R @ est.t + t)
    c = est.R @ trk.center[obj] + est.t
    if np.linalg.norm(R @ c + t - c) < trk.config.carry_keep_moving:
        return False
    return seen_where_it_was(trk, obj, depth, pose=moved) > seen_where_it_was(trk, obj, depth)


def moved_from(trk, obj: int) -> Pose:
    """The pose (camera frame) that this frame's hand motion moves carried part ``obj`` from in the
    ``carry_keep_moving`` test: its estimate, or, with ``carry_keep_moving_pre_reseed`` and ``carry_over_sliver``, for a
    part the colour stage has just re-seeded on its blob, its estimate before that re-seed: the hand's registration
    started there (:func:`follow_hands` registers around it) and ``carry_over_sliver`` moves the part from there, while
    the re-seeded estimate already holds part of the frame's motion (along its blob), which the hand's step would add
    a second time."""
    cfg = trk.config
    pre = trk._pre_reseed.get(obj) if (cfg.carry_keep_moving_pre_reseed and cfg.carry_over_sliver) else None
    return trk.estimates[trk.names[obj]] if pre is None else pre


def blob_centre(det) -> np.ndarray | None:
    """Pixel centroid (u, v) of a detection's blob, or None."""
    center = getattr(det, "center", None) if det is not None else None
    return None if center is None else np.asarray(center, np.float64)


def anchor_at_start(trk, started: np.ndarray) -> None:
    """``carry_anchor_start``: the parts whose carry ``started`` (K,) this frame take their estimate (camera frame,
    before this frame's hand motion, which then moves the anchor with them) as rest anchor."""
    for i in np.nonzero(started)[0]:
        est = trk.estimates[trk.names[i]]
        trk._rest_t[i], trk._rest_R[i] = est.t.copy(), est.R.copy()


def carry_onto_blob(trk, obj: int, R: np.ndarray, t: np.ndarray, det) -> bool:
    """Carried part ``obj``, which the colour stage has just put on its blob's ray at the blob's depth or, without
    depth on the blob, at its old depth (:func:`~tracker.filter.colour_input.reseed`), is turned by the hand's motion
    this frame (x ↦ ``R`` x + ``t``, camera frame, m) and put on that ray at the depth the hand's motion takes its
    centre from where it was before that re-seed (``carry_blob_depth``): the blob says where across the image, the hand
    how far and how turned. Returns whether it was moved."""
    pre = trk._pre_reseed.get(obj)
    center = getattr(det, "center", None) if det is not None else None
    if pre is None or center is None:
        return False
    z = float((R @ (pre.R @ trk.center[obj] + pre.t) + t)[2])
    if z <= 0.05:
        return False
    target = pixel_rays(trk.intrinsics, np.array([float(center[0])]), np.array([float(center[1])]))[0] * z
    move_part(trk, obj, R, target - R @ centre(trk, obj))
    return True


def out_of_table(trk, obj: int, plane) -> None:
    """Carried part ``obj`` moved below the table top (``plane`` = (normal, offset), camera frame) by more than a
    millimetre is moved up along the normal until it touches it (``carry_above_table``): a hand cannot push a part
    through the table, a registration lagging the hand's descent can."""
    est = trk.estimates[trk.names[obj]]
    h = lowest_height(trk, obj, est.R, est.t, plane)
    if h < -0.001:
        move_part(trk, obj, np.eye(3), -h * np.asarray(plane[0], np.float64))


def lifted_off(trk, obj: int, position: np.ndarray, new_position: np.ndarray, height: float, plane) -> bool:
    """Is carried part ``obj`` one the hand has set down and now rises from (``carry_release_on_lift``): carried in the
    air (lowest point above ``carry_min_height``), then with its lowest point within ``carry_min_height`` of
    the table for ``carry_release_on_lift`` frames in a row (a part picked up from the table is not), and
    the hand's motion (``position`` → ``new_position``, camera frame, m) would raise it from the table by more than
    ``carry_lift_m``? (The hand's step is seen from the camera: a camera moving by more than ``carry_lift_m`` per
    frame along the table normal would count as well.)"""
    cfg = trk.config
    if cfg.carry_release_on_lift <= 0 or plane is None or not np.isfinite(height):
        return False
    if trk._carry.set_down[obj] < cfg.carry_release_on_lift:
        return False
    return float((new_position - position) @ plane[0]) > cfg.carry_lift_m


STILL_STEP_M = 0.002
"""Largest step (m) of the hand's motion in a frame that counts as the hand standing still (carry_set_down_m)."""
STILL_FRAMES = 2
"""Frames in a row the hand stands still with the part near the table before the part counts as put down."""


def held_where_put(trk, obj: int, position: np.ndarray, new_position: np.ndarray, height: float, plane) -> str:
    """Has the hand put carried part ``obj`` down (``carry_set_down_m``)? ``"hold"``: it stays where it was put (not
    moved with the hand this frame), ``"release"``: the hand rises from it (let go), ``"follow"``: it moves with the
    hand as before. ``position`` → ``new_position``: where the hand's motion this frame would take it (camera frame,
    m); ``height``: its lowest point above the table before this motion (m); ``plane``: the table's (normal, offset).

    A hand that has carried a part through the air and then stands still (steps of at most ``STILL_STEP_M``) for
    ``STILL_FRAMES`` frames with the part's lowest point within ``carry_set_down_m`` of the table has put it down: the
    part is moved along the normal onto the table (a carried part rides as high as its offset from the hand was
    wrong; by up to a centimetre here, which kept ``carry_release_on_lift``'s height test from ever counting it set
    down) and held there while the hand opens, whose fingers moving apart the hand's registration reads as a slide.
    The hand rising by more than ``carry_lift_m`` in a frame lets go of it; the hand moving on along the table by more
    than ``carry_set_down_slide_m`` since takes it along again (a part pushed along the table). With
    ``carry_set_down_on_parts`` a part put on top of another is put down on that part's top (:func:`surface_below`)
    the same way."""
    cfg = trk.config
    carry = trk._carry
    if cfg.carry_set_down_m <= 0 or plane is None or not np.isfinite(height):
        return "follow"
    n = np.asarray(plane[0], np.float64)
    if cfg.carry_set_down_on_parts:
        height = height - surface_below(trk, obj, plane)  # above the part it is put on, or the table
    step = np.asarray(new_position, np.float64) - np.asarray(position, np.float64)
    if carry.put_down[obj]:
        if float(step @ n) > cfg.carry_lift_m:
            return "release"
        carry.slide[obj] += step
        along = carry.slide[obj] - float(carry.slide[obj] @ n) * n
        if float(np.linalg.norm(along)) <= cfg.carry_set_down_slide_m:
            return "hold"
        carry.end_put_down(obj)
        return "follow"
    still = carry.was_in_air[obj] and height <= cfg.carry_set_down_m and float(np.linalg.norm(step)) <= STILL_STEP_M
    carry.still[obj] = carry.still[obj] + 1 if still else 0
    if carry.still[obj] < STILL_FRAMES:
        return "follow"
    move_part(trk, obj, np.eye(3), -height * n)  # its lowest point onto the table
    if cfg.table_upright and trk.meshes[obj] is None:
        set_down_upright(trk, obj, plane)
    carry.put_down[obj] = True
    return "hold"


def surface_below(trk, obj: int, plane) -> float:
    """Height (m) above the table plane ``(n, d)`` of the surface part ``obj`` would be put down on: the highest top of
    a part that is not carried, lies below ``obj``'s lowest point (within 1 cm) and whose centre is within 0.3 × the
    sum of the two bounding radii of ``obj``'s along the table (a cube on top of another, not beside it); 0 (the
    table) when there is none."""
    n = np.asarray(plane[0], np.float64)
    est = trk.estimates[trk.names[obj]]
    low = lowest_height(trk, obj, est.R, est.t, plane)
    carried = trk._carry.carried
    top = 0.0
    for o, name in enumerate(trk.names):
        if o == obj or carried[o]:
            continue
        other = trk.estimates[name]
        gap = est.t - other.t
        along = gap - float(gap @ n) * n
        if float(np.linalg.norm(along)) > 0.3 * (trk._carry.radii[obj] + trk._carry.radii[o]):
            continue
        h = highest_height(trk, o, other.R, other.t, plane)
        if top < h <= low + 0.01:
            top = h
    return top


def estimate_rect(trk, obj: int, shape: tuple[int, ...], pose: Pose | None = None) -> tuple[int, int, int, int] | None:
    """Pixel rectangle ``(u0, v0, u1, v1)`` (end-exclusive, clipped to an image of ``shape``; may be empty) of part
    ``obj``'s bounding box at its estimate (or ``pose``), or None when a corner lies closer than 5 cm to the camera."""
    fp = footprint(trk, obj, pose)
    if fp is None:
        return None
    h, w = shape[:2]
    return (max(int(np.floor(fp[0])), 0), max(int(np.floor(fp[1])), 0), min(int(np.ceil(fp[2])) + 1, w),
            min(int(np.ceil(fp[3])) + 1, h))


SEEN_TOLERANCE_M = 0.01
"""Metres: a silhouette pixel whose depth is this close to the estimate's surface shows the part (carry_keep_unseen)."""


def seen_where_it_was(trk, obj: int, depth: np.ndarray, stride: int = 2, pose: Pose | None = None) -> float:
    """Fraction of box part ``obj``'s silhouette at its current estimate (or at ``pose``, camera frame; every
    ``stride``-th pixel of its projected rectangle) where ``depth`` (metres) lies within ``SEEN_TOLERANCE_M`` of the
    rendered surface: how much of the part this frame's depth still shows where the estimate is. 1.0 (shown) for a
    mesh part or an estimate off the image, so that nothing is kept in a hand on that account."""
    rect = None if trk.meshes[obj] is not None else estimate_rect(trk, obj, depth.shape, pose)
    if rect is None:
        return 1.0
    u0, v0, u1, v1 = rect
    if u1 <= u0 or v1 <= v0:
        return 1.0
    vv, uu = np.mgrid[v0:v1:stride, u0:u1:stride]
    uu, vv = uu.ravel(), vv.ravel()
    surface = box_surface_depth(trk, obj, uu, vv, pose)
    on = np.isfinite(surface)
    if not on.any():
        return 1.0
    z = depth[vv[on], uu[on]]
    with np.errstate(invalid="ignore"):
        shown = np.abs(z - surface[on]) < SEEN_TOLERANCE_M
    return float(shown.mean())


def revealed(trk, obj: int, depth: np.ndarray) -> bool:
    """Does the depth camera see through hidden part ``obj``'s estimate: valid depth on at least
    ``carry_revealed_fraction`` of the middle half of its projected bounding rectangle, nearly all of it more than
    1.5 cm behind the part (behind its far side; with ``revealed_surface``, behind the estimate's rendered surface at
    each pixel, so that the table right under a resting box counts)? Then the part is not where it was (a hand
    snatched it while hiding it, or it was pushed away)."""
    if trk.config.revealed_surface and trk.meshes[obj] is None:
        # the rectangle, the valid pixels and the surface behind them in one compiled call (_behind_surface: the
        # values of estimate_rect, of box_surface_depth at np.nonzero(valid)'s pixels and of the masks' means)
        est = trk.estimates[trk.names[obj]]
        intr = trk.intrinsics
        size, n_valid, n_on, n_behind = _behind_surface(
            np.ascontiguousarray(trk.corners[obj], np.float64), np.ascontiguousarray(est.R, np.float64), est.t,
            np.ascontiguousarray(trk.center[obj], np.float64), np.ascontiguousarray(trk.half[obj], np.float64),
            float(intr.fx), float(intr.fy), float(intr.cx), float(intr.cy), depth)
        if size >= 0:
            if size < 16 or n_valid / size < trk.config.carry_revealed_fraction:
                return False
            if n_valid == 0 or n_on / n_valid < 0.5:  # (no valid pixel: the numpy form's NaN means said False)
                return False
            return bool(n_behind / n_on > 0.9)
    rect = estimate_rect(trk, obj, depth.shape)
    if rect is None:
        return False
    u0, v0, u1, v1 = rect
    # the middle half of the rectangle: the silhouette of a box, whatever its turn, covers it
    du, dv = (u1 - u0) // 4, (v1 - v0) // 4
    patch = depth[v0 + dv : v1 - dv, u0 + du : u1 - du]
    if patch.size < 16:
        return False
    valid = np.isfinite(patch) & (patch > 0)
    if valid.mean() < trk.config.carry_revealed_fraction:
        return False
    if trk.config.revealed_surface and trk.meshes[obj] is None:
        vv, uu = np.nonzero(valid)
        surface = box_surface_depth(trk, obj, uu + u0 + du, vv + v0 + dv)
        on = np.isfinite(surface)
        if on.mean() < 0.5:
            return False
        behind = patch[valid][on] > surface[on] + 0.015
    else:
        est = trk.estimates[trk.names[obj]]
        behind = patch[valid] > (trk.corners[obj] @ est.R.T + est.t)[:, 2].max() + 0.015  # its far side
    return bool(behind.mean() > 0.9)


@nb.njit(cache=True)
def _behind_surface(corners, R, t, center, half, fx, fy, cx, cy, depth):
    """:func:`revealed`'s surface test for the box ``(center, half)`` with bounding-box corners ``corners`` at
    ``(R, t)``: over the middle half of its :func:`estimate_rect` (the footprint of
    :func:`~tracker.filter.footprint_depth.footprint_rect`) in ``depth``, the pixels (``size``; 0: no rectangle,
    -1: one off the image), the valid ones (finite, > 0), those on the box's silhouette and those among them more
    than 1.5 cm behind its rendered surface (:func:`~tracker.geometry.box_renderer.box_depths`, row-major pixel
    order)."""
    ok, u0, v0, u1, v1 = footprint_rect(corners, R, t, fx, fy, cx, cy, depth.shape[0], depth.shape[1])
    if not ok:
        return 0, 0, 0, 0
    if u1 <= u0 or v1 <= v0:
        return -1, 0, 0, 0  # a rectangle off the image: numpy's slices of it are left to the numpy form
    du, dv = (u1 - u0) // 4, (v1 - v0) // 4
    a0, a1, b0, b1 = u0 + du, u1 - du, v0 + dv, v1 - dv
    if a1 <= a0 or b1 <= b0:
        return 0, 0, 0, 0
    m = 0
    for v in range(b0, b1):
        for u in range(a0, a1):
            z = depth[v, u]
            if np.isfinite(z) and z > 0:
                m += 1
    pu = np.empty(m)
    pv = np.empty(m)
    zs = np.empty(m)
    m = 0
    for v in range(b0, b1):
        for u in range(a0, a1):
            z = depth[v, u]
            if np.isfinite(z) and z > 0:
                pu[m] = u
                pv[m] = v
                zs[m] = z
                m += 1
    surface = box_depths(R, t, center, half, pu, pv, fx, fy, cx, cy)
    n_on = 0
    n_behind = 0
    for i in range(m):
        if np.isfinite(surface[i]):
            n_on += 1
            if zs[i] > surface[i] + 0.015:
                n_behind += 1
    return (a1 - a0) * (b1 - b0), m, n_on, n_behind


def take_shadow(trk, obj: int, pos: np.ndarray, min_shift: float | None = None) -> bool:
    """Part ``obj`` is not where it was (:func:`revealed`): if the hand that hid it went away
    (:class:`~tracker.filter.hand_carry.Shadow`, moved by more than the part's bounding radius), the part went with
    it: it is shifted by the hand's motion since and carried on if the hand is still in view. Returns whether it
    was. With ``min_shift`` (m, ``carry_shadow_take_m``) the part's place need not be seen through: a hand still in
    view that has moved that far from where it hid the part, the part still hidden, has taken it (its place may stay
    under the arm for many frames); a part left behind shows its blob again and is put back on it."""
    sh = trk._carry.shadows[obj]
    bound = trk._carry.radii[obj] if min_shift is None else min_shift
    if sh is None or np.linalg.norm(sh.t) < bound or (min_shift is not None and sh.patch is None):
        return False
    trk._carry.take_shadow(obj)
    move_part(trk, obj, np.eye(3), sh.t)
    pos[obj] = pos[obj] + sh.t
    return True


def grab(trk, obj: int, depth: np.ndarray, pos: np.ndarray, plane) -> None:
    """Part ``obj`` is not where it was (:func:`revealed`): if a hand is near (enough points above the table within
    1.5 × ``carry_radius``, other parts' estimates left out), the part is in it: moved to those points' centroid
    and carried from there on; else nothing changes (re-seeding finds the part when its blob shows)."""
    k = len(trk.parts)
    carry = trk._carry
    exclude = [(pos[o], carry.radii[o] + 0.005) for o in range(k) if o != obj and not carry.carried[o]]
    pts = carry._points(depth, pos[obj], 1.5 * trk.config.carry_radius, plane, exclude)
    if pts.shape[0] < trk.config.carry_min_points:
        return
    est = trk.estimates[trk.names[obj]]
    d = pts.mean(axis=0) - (est.R @ trk.center[obj] + est.t)
    move_part(trk, obj, np.eye(3), d)
    pos[obj] = pos[obj] + d
    near = ((pts - pts.mean(axis=0)) ** 2).sum(1) <= trk.config.carry_radius**2
    carry.start(obj, pts[near] if near.sum() >= trk.config.carry_min_points else pts)


def blob_disagrees(trk, obj: int, position: np.ndarray, centroid: np.ndarray | None) -> bool:
    """Is the centroid (pixels) of part ``obj``'s confident blob farther than ``carry_blob_radii`` projected bounding
    radii from the part's centre when its origin is at ``position`` (m, camera frame)? A sliver's centroid lies within
    one radius of the centre, so a carried part whose blob shows farther away is not where the hand took it."""
    if centroid is None or trk.config.carry_blob_radii <= 0:
        return False
    c = trk.estimates[trk.names[obj]].R @ trk.center[obj] + position
    if c[2] <= 0.05:
        return False
    uv = trk.intrinsics.project(c[None])[0]
    rpx = trk._radius[obj] * trk.intrinsics.fx / float(c[2])
    return bool(np.hypot(*(uv - centroid)) > trk.config.carry_blob_radii * rpx)


def update_support(trk, unseen: np.ndarray, pos: np.ndarray, heights: np.ndarray, plane) -> None:
    """Which parts get the support prior: ``unseen`` (little depth evidence, not carried) and not on another
    part. Their rest anchors, when in the air (last seen in a hand), are set down on the table too."""
    k = len(trk.parts)
    trk._support_on = np.zeros(k, bool)
    if plane is None or trk.config.support_prior_sigma <= 0:
        return
    for i in np.nonzero(unseen & ~trk._blob_moved)[0]:
        if supported_by_other(i, pos, heights, trk._carry.radii, margin=0.01):
            continue
        trk._support_on[i] = True
        if trk.config.table_upright and trk.meshes[i] is None:
            trk._rest_R[i] = upright(trk._rest_R[i], plane[0])
        h = lowest_height(trk, i, trk.estimates[trk.names[i]].R, trk._rest_t[i], plane)
        if h > trk.config.carry_min_height:
            trk._rest_t[i] = trk._rest_t[i] - h * plane[0]


def upright_resting(trk, state, plane) -> None:
    """``resting_upright_deg``: every box part that rests on the table — lowest point within ``carry_min_height`` of
    the table plane ``(normal, offset)`` (camera frame), not carried, not moving with its blob, not moved by more
    than ``carry_min_motion`` in the carry test's window — whose estimate is tilted from lying on a face by less
    than ``resting_upright_deg`` is turned upright about its centre (:func:`set_down_upright`); ``state.poses``
    gets the new estimates. A box on a flat table lies on a face; a
    refinement that sees only some of its faces (another part on top of it or in front) can tilt it."""
    max_tilt = np.radians(trk.config.resting_upright_deg)
    if max_tilt <= 0 or plane is None:
        return
    normal = np.asarray(plane[0], np.float64)
    moved = trk._carry.moved()  # distance travelled in the carry test's window (m), 0 for parts with no history
    for i, name in enumerate(trk.names):
        if (trk.meshes[i] is not None or trk._carry.carried[i] or trk._blob_moved[i]
                or moved[i] > trk.config.carry_min_motion):
            continue  # a part that moves may be in a hand that tilts it
        est = trk.estimates[name]
        tilt = float(np.arccos(np.clip(np.abs(est.R.T @ normal).max(), -1.0, 1.0)))
        if tilt < 1e-6 or tilt > max_tilt:
            continue
        if set_down_upright(trk, i, plane):
            state.poses[name] = trk.estimates[name]
            state.particles[name] = trk.p[:, i].astype(np.float32)


def set_down_upright(trk, obj: int, plane, anywhere: bool = False) -> bool:
    """If box part ``obj`` would touch the table (``plane`` = (normal, offset), camera frame) when turned upright
    about its centre (lowest point within ``carry_min_height``; with ``anywhere`` at any height: a part carried in
    the air, ``carry_upright_air``), turn it so (:func:`upright`); returns whether it did."""
    est = trk.estimates[trk.names[obj]]
    R_up = upright(est.R, plane[0])
    c = est.R @ trk.center[obj] + est.t
    if not anywhere and lowest_height(trk, obj, R_up, c - R_up @ trk.center[obj], plane) > trk.config.carry_min_height:
        return False
    Q = R_up @ est.R.T
    move_part(trk, obj, Q, c - Q @ c)
    return True


def upright(R: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """The rotation nearest to ``R`` (body → camera) at which a box lies on a face of a table with unit ``normal``
    (camera frame): the body axis most nearly along ±normal is turned onto it by the least rotation."""
    dots = R.T @ normal
    j = int(np.argmax(np.abs(dots)))
    a = R[:, j] * np.sign(dots[j])
    axis = np.cross(a, normal)
    s, c = float(np.linalg.norm(axis)), float(np.clip(a @ normal, -1.0, 1.0))
    if s < 1e-12:
        return R
    return rotvec_to_matrix(axis / s * np.arctan2(s, c))[0] @ R


def lowest_height(trk, obj: int, R: np.ndarray, t: np.ndarray, plane) -> float:
    """Height (m) above the table plane ``(n, d)`` of part ``obj``'s lowest vertex at pose (R, t)."""
    n, d = plane
    return float((trk.hulls[obj] @ (R.T @ n)).min() + t @ n + d)


def highest_height(trk, obj: int, R: np.ndarray, t: np.ndarray, plane) -> float:
    """Height (m) above the table plane ``(n, d)`` of part ``obj``'s highest vertex at pose (R, t)."""
    n, d = plane
    return float((trk.hulls[obj] @ (R.T @ n)).max() + t @ n + d)


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
    out = np.zeros(p.shape[0])
    for i in np.nonzero(trk._support_on)[0]:
        out -= _support_term(trk, p, R, plane, i)
    return out


class PriorTerms:
    """:func:`log_rest_prior` and :func:`log_support_prior` during one frame's coordinate passes, kept per part so
    that a pass recomputes only the parts it moved (each part's term computed as those functions compute it, the
    sums formed as they form them: the same values); :meth:`take` follows a resampling. The parts under either
    prior and their anchors do not change during the passes."""

    def __init__(self, trk, plane) -> None:
        self.trk = trk
        self.plane = plane
        k = len(trk.parts)
        self.support_parts = np.flatnonzero(trk._support_on) if plane is not None else np.zeros(0, np.int64)
        n = trk.config.n_particles
        self.support_cols = np.zeros((k, n)) if self.support_parts.size else None  # per part, its support term
        self.done = np.zeros(k, bool)
        # the parts under the rest prior, found once (log_rest_prior's tests, done here for the frame)
        self.rest_parts = np.flatnonzero(trk._rest_on)

    def total(self, p: np.ndarray, R: np.ndarray,
              changed: set[int] | None = None) -> tuple[np.ndarray | float, np.ndarray | float]:
        """``(log_rest_prior(trk, p), log_support_prior(trk, p, R, plane))`` as the passes add them, where only the
        parts in ``changed`` moved since the last call (``None``: all)."""
        trk = self.trk
        rest = log_rest_prior(trk, p, self.rest_parts)  # its parts found once in __init__; cheaper from scratch
        support = 0.0
        if self.support_parts.size:
            for i in self.support_parts:
                if changed is None or i in changed or not self.done[i]:
                    self.support_cols[i] = _support_term(trk, p, R, self.plane, i)
                    self.done[i] = True
            support = np.zeros(p.shape[0])
            for i in self.support_parts:
                support -= self.support_cols[i]
        return rest, support

    def take(self, idx: np.ndarray) -> None:
        """Follow a resampling: the particles are now the rows ``idx`` of the previous ones."""
        if self.support_cols is not None:
            self.support_cols = self.support_cols[:, idx]


def _support_term(trk, p, R, plane, i) -> np.ndarray:
    """Part ``i``'s term of :func:`log_support_prior` (subtracted from it); one kernel (:func:`_support_kernel`) from
    two particles on."""
    sig = trk.config.support_prior_sigma
    n, d = plane
    if p.shape[0] >= 2:
        return _support_kernel(np.asarray(p, np.float64), np.asarray(R, np.float64),
                               np.ascontiguousarray(n, np.float64).reshape(3), float(d),
                               np.ascontiguousarray(trk.hulls[i], np.float64), int(i), float(sig))
    return _support_numpy(p, R, n, d, trk.hulls[i], i, sig)


def _support_numpy(p, R, n, d, hull, i, sig) -> np.ndarray:
    """:func:`_support_term` in numpy (the reference :func:`_support_kernel` is tested against)."""
    up = np.einsum("nji,j->ni", R[:, i], n)  # Rᵀ n per particle: the table's normal in the part's frame
    h = np.abs((up @ hull.T).min(axis=1) + p[:, i] @ n + d) / sig
    return np.where(h < 3.0, 0.5 * h * h, 3.0 * h - 4.5)


@nb.njit(cache=True)
def _support_kernel(p, R, n, d, hull, i, sig):
    """:func:`_support_numpy` for two or more particles, its operations in the order numpy forms them here (einsum's
    plain sums for Rᵀ n; the hull product and the particles' ``p · n`` with the fused multiply-adds of numpy's
    matrix products on this project's machines, :mod:`tracker.geometry.fma`): the same values."""
    m = p.shape[0]
    out = np.empty(m)
    for j in range(m):
        u0 = (R[j, i, 0, 0] * n[0] + R[j, i, 1, 0] * n[1]) + R[j, i, 2, 0] * n[2]
        u1 = (R[j, i, 0, 1] * n[0] + R[j, i, 1, 1] * n[1]) + R[j, i, 2, 1] * n[2]
        u2 = (R[j, i, 0, 2] * n[0] + R[j, i, 1, 2] * n[1]) + R[j, i, 2, 2] * n[2]
        low = np.inf
        for v in range(hull.shape[0]):
            x = fma(u2, hull[v, 2], fma(u1, hull[v, 1], u0 * hull[v, 0]))
            if x < low or np.isnan(x):
                low = x
        pn = fma(p[j, i, 2], n[2], fma(p[j, i, 0], n[0], p[j, i, 1] * n[1]))
        h = abs(low + pn + d) / sig
        out[j] = 0.5 * h * h if h < 3.0 else 3.0 * h - 4.5
    return out


def warm_up() -> None:
    """Load (or compile) the kernels of the rest and support priors and of the see-through and footprint tests on
    tiny inputs of the types the stage gives them (they run only once a part rests hidden or is held to the
    table)."""
    p = np.zeros((2, 1, 3))
    p[..., 2] = 0.5
    R = np.tile(np.eye(3), (2, 1, 1, 1))
    _rest_prior(p, np.zeros(1, np.int64), np.zeros((1, 3)), 1e-4)
    _support_kernel(p, R, np.array([0.0, 0.0, -1.0]), 0.6, np.full((8, 3), 0.01), 0, 0.002)
    # the see-through and footprint tests' kernels (a hidden part), on a float32 depth image as frames give it
    corners = np.array([[x, y, z] for x in (-0.02, 0.02) for y in (-0.02, 0.02) for z in (-0.02, 0.02)])
    depth = np.full((8, 8), 0.6, np.float32)
    args = (corners, np.eye(3), np.array([0.0, 0.0, 0.5]), np.zeros(3), np.full(3, 0.02), 10.0, 10.0, 4.0, 4.0, depth)
    _behind_surface(*args)
    _footprint_counts(*args, 2)


def log_rest_prior(trk, p, parts: np.ndarray | None = None) -> np.ndarray | float:
    """Rest prior (TrackerConfig.rest_prior_sigma): Gaussian pull of resting hidden parts to their anchors.
    ``parts``: ``np.flatnonzero(trk._rest_on)`` when the caller has it (:class:`PriorTerms`, once a frame)."""
    if parts is None:
        parts = np.flatnonzero(trk._rest_on)
    if not parts.size:
        return 0.0
    sig2 = trk.config.rest_prior_sigma ** 2
    if parts.size < 8:  # numpy sums fewer than 8 terms in order (from 8 on, pairwise): the kernel's sums
        return _rest_prior(np.asarray(p, np.float64), parts, np.asarray(trk._rest_t, np.float64), float(sig2))
    d2 = ((p[:, parts] - trk._rest_t[parts]) ** 2).sum(-1)
    return -0.5 * np.minimum(d2, 9.0 * sig2).sum(-1) / sig2


@nb.njit(cache=True)
def _rest_prior(p, parts, rest_t, sig2):
    """:func:`log_rest_prior` of the particles ``p`` (N, K, 3) for the listed parts (fewer than 8) with anchors
    ``rest_t`` (K, 3): numpy's operations in its order (the squares summed in order, then the parts' clipped
    terms), the same values."""
    n = p.shape[0]
    out = np.empty(n)
    for j in range(n):
        acc = 0.0
        for q in range(parts.shape[0]):
            i = parts[q]
            dx = p[j, i, 0] - rest_t[i, 0]
            dy = p[j, i, 1] - rest_t[i, 1]
            dz = p[j, i, 2] - rest_t[i, 2]
            c = min((dx * dx + dy * dy) + dz * dz, 9.0 * sig2)
            acc = c if q == 0 else acc + c
        out[j] = -0.5 * acc / sig2
    return out



def update_rest_anchors(trk: MultiObjectTracker, detected: np.ndarray) -> None:
    """Well-seen parts (reliable blob, visible enough) move their rest-prior anchors to their new estimates."""
    cfg = trk.config
    if cfg.rest_prior_sigma > 0:
        well = detected & (trk.visibility >= cfg.visible_fraction_full)
        for i in np.nonzero(well)[0]:
            trk._rest_t[i] = trk.estimates[trk.names[i]].t
            trk._rest_R[i] = trk.estimates[trk.names[i]].R


def off_anchor(trk: MultiObjectTracker) -> np.ndarray:
    """Per part, the distance (m, camera frame) from its rest-prior anchor to its current estimate."""
    now = np.array([trk.estimates[nm].t for nm in trk.names])
    return np.linalg.norm(now - trk._rest_t, axis=1)


def update_moving_anchors(trk: MultiObjectTracker) -> None:
    """Parts that move (carried, moving with their blob or, with ``rest_anchor_motion``, placed by the depth more than
    ``carry_min_motion`` from their anchor) and that this frame's refinement placed take their
    refined estimate as rest anchor (``rest_anchor_moving``): the anchor of a part picked up half in the hand is
    its last seen pose, not its last fully seen one, which the hand has since moved and turned."""
    if trk.config.rest_prior_sigma <= 0 or not trk.config.rest_anchor_moving:
        return
    moving = np.asarray(trk._carry.carried, bool) | np.asarray(trk._blob_moved, bool)
    if trk.config.rest_anchor_motion:
        moving |= off_anchor(trk) > trk.config.carry_min_motion
    for i in np.nonzero(moving)[0]:
        if placed_by_depth(trk, i):
            trk._rest_t[i] = trk.estimates[trk.names[i]].t
            trk._rest_R[i] = trk.estimates[trk.names[i]].R
