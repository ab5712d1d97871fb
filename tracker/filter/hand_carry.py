"""Hidden parts carried by a hand follow the hand's depth points (not in the seed; an addition of the tracker).

A part that vanishes inside a grasp gives the depth likelihood nothing to work with: every pixel over it shows the
hand, and the colour detector finds no blob. Parts do not float and do not move on their own, so a hidden part is
either at rest (the rest prior holds it, see :class:`~tracker.filter.tracker_config.TrackerConfig.rest_prior_sigma`) or
in the hand that hides it. It is taken to be in the hand when, as it disappeared, it was moving (its estimate
travelled more than ``carry_min_motion`` in the last ``carry_window_s`` seconds) or it was in the air (its lowest
point more than ``carry_min_height`` above the table with no other part under it).

The hand is followed through its depth points above the table (camera frame, metres) near the part: every frame
the patch of points within ``carry_radius`` of the part's previous position is registered to the current points
by rigid point-to-plane ICP (nearest neighbours closer than 2 cm, ``carry_iterations`` rounds; the rotation about
the patch's centroid, damped where the patch does not constrain it, at most ``carry_max_turn`` per frame, about the
table normal only with ``carry_rotation_axis = 'table'``; translation only with ``carry_rotation`` off), and the part
moves rigidly with the hand. A registration rather than a centroid: a centroid slides up the arm as more of it
enters the window. Points on other parts' estimates are left out, so a hand passing a resting part does not take it
along. The carry ends when the part is seen again in depth (visible fraction back above
``rest_prior_max_visibility``; the likelihood and re-seeding take over) or when fewer than ``carry_min_points`` hand
points are left near the part (the hand is gone: the part was put down where it is). The hidden-parts stage
(:mod:`tracker.filter.hidden_parts`) also ends it when the part's blob shows up again away from the hand, or stays
put while the hand moves on, and starts it for a part whose place the camera sees through (snatched while hidden).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from tracker.filter.motion_model import rotvec_to_matrix
from tracker.geometry import projective_icp
from tracker.geometry.camera import Intrinsics
from tracker.geometry.depth_points import window_points
from tracker.geometry.point_icp import build_grid, rigid_icp
from tracker.geometry.projective_icp import refine_projective


@dataclass
class Carry:
    """One carried part: hand anchor ``anchor`` (camera frame, m) and the part's offset ``offset`` from it (m)."""

    anchor: np.ndarray
    offset: np.ndarray


def above_table_points(depth: np.ndarray, intrinsics: Intrinsics, center: np.ndarray, radius: float,
                       plane: tuple[np.ndarray, float] | None, min_height: float, stride: int,
                       exclude: list[tuple[np.ndarray, float]]) -> np.ndarray:
    """Camera-frame points (M, 3) of the depth image within ``radius`` m of ``center`` and more than ``min_height``
    above the table plane (``(normal, offset)``, height = n·x + offset; no plane = no height test), every
    ``stride``-th pixel, without points inside the spheres ``exclude`` [(centre, radius)]."""
    z = float(center[2])
    if not np.isfinite(z) or z <= 0.05:
        return np.zeros((0, 3))
    fx, fy, cx, cy = intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy
    h, w = depth.shape
    zmin = max(z - radius, 0.05)
    u_c, v_c = fx * center[0] / z + cx, fy * center[1] / z + cy
    ru, rv = fx * radius / zmin, fy * radius / zmin
    u0, u1 = max(int(u_c - ru), 0), min(int(u_c + ru) + 1, w)
    v0, v1 = max(int(v_c - rv), 0), min(int(v_c + rv) + 1, h)
    if u0 >= u1 or v0 >= v1:
        return np.zeros((0, 3))
    use_plane = plane is not None
    normal = np.asarray(plane[0], np.float64) if use_plane else np.zeros(3)
    offset = float(plane[1]) if use_plane else 0.0
    ex_c = np.array([c for c, _ in exclude], np.float64).reshape(-1, 3)
    ex_r2 = np.array([r * r for _, r in exclude], np.float64)
    return window_points(depth, u0, u1, v0, v1, int(stride), float(fx), float(fy), float(cx), float(cy),
                         np.asarray(center, np.float64), radius * radius, normal, offset, float(min_height), use_plane,
                         ex_c, ex_r2)


PAIR_BOUND = 0.02
"""Largest distance (m) of a nearest-neighbour pair in the hand-patch registrations."""

KEY_STEP, KEY_TURN, KEY_INLIER = 0.005, 0.05, 0.005
"""Largest correction (m, rad) the keyframe registration (``carry_keyframe``) makes to a frame's hand motion, and
the distance (m) within which a keyframe point counts as still on the hand."""

SHADOW_POINTS = 200
SHADOW_ITERATIONS = 8
"""Patch points and rounds of a shadow carry's registration (a point-to-point shift, :func:`register_shift`, of
at most 200 patch points onto the current window's points): it runs for every resting part under a hand, so it must
be cheap, and it only has to say where a snatched part went to within a few centimetres; the carry and the filter
take over from there."""


@dataclass
class Shadow:
    """Where a hidden resting part would be had the hand over it taken it along (``carry_shadow``): the hand's shift
    ``t`` since the part was hidden (camera frame, m; followed as a shift, the part keeps its rotation), its hand patch
    (camera frame, m; None once the hand has gone) and its last step (m; the next registration's first guess)."""

    patch: np.ndarray | None
    t: np.ndarray
    step: np.ndarray


class HandCarry:
    """Decides which hidden parts are carried and moves them with the hand's depth points; see the module doc."""

    def __init__(self, n_parts: int, config, intrinsics: Intrinsics, radii: np.ndarray):
        self.config = config
        self.intrinsics = intrinsics
        self.radii = np.asarray(radii, np.float64)  # bounding radius per part (m)
        self.patches: list[np.ndarray | None] = [None] * n_parts  # hand points near each carried part, last frame
        self.keys: list[np.ndarray | None] = [None] * n_parts  # carry_keyframe: keyframe hand patch, moved to now (m)
        self.last_step = np.zeros((n_parts, 3))  # last frame's hand translation per part (initial guess, m)
        self.last_turn = np.zeros((n_parts, 3))  # last frame's hand rotation vector per part (initial guess, rad)
        self.history: deque[tuple[float, np.ndarray]] = deque()  # (time s, positions (K, 3))
        self._prev_depth: np.ndarray | None = None  # last frame's depth image (carry start registration)
        self._prev_motion: np.ndarray | None = None  # 4×4 camera motion since that image (None: the camera stayed)
        self.shadows: list[Shadow | None] = [None] * n_parts  # hidden resting parts' would-be carries
        self.was_in_air = np.zeros(n_parts, bool)  # the carried part has been in the air during this carry
        self.set_down = np.zeros(n_parts, np.int64)  # frames in a row it has then been on the table (note_heights)
        # carry_set_down_m: frames in a row the hand has stood still with the part near the table, whether the part
        # is held where the hand put it down, and the hand's motion since (camera frame, m)
        self.still = np.zeros(n_parts, np.int64)
        self.put_down = np.zeros(n_parts, bool)
        self.slide = np.zeros((n_parts, 3))
        # carry_backtrack: the last depth images (oldest first) with the camera motion since each (4×4, old camera
        # frame → current; None: the camera stayed), and per part the pose the refinement last placed it at
        # (current camera frame) and the frames completed since (-1: never placed)
        self._ring: deque[list] = deque(maxlen=int(config.carry_backtrack) + 1)
        self.placed_R = np.repeat(np.eye(3)[None], n_parts, axis=0)
        self.placed_t = np.zeros((n_parts, 3))
        self.placed_age = np.full(n_parts, -1, np.int64)
        # carry_start_placed_step: the step between the last two placements (current camera frame, m), and whether
        # they were in consecutive frames
        self.placed_step = np.zeros((n_parts, 3))
        self.placed_step_ok = np.zeros(n_parts, bool)
        self._start_guess: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # this frame's extra first registrations
        self.backtracked = np.zeros(n_parts, bool)  # this frame's carry starts from a backtracked pose

    @property
    def carried(self) -> np.ndarray:
        """(K,) bool: which parts are being carried now."""
        return np.array([p is not None for p in self.patches], bool)

    def release(self, obj: int) -> None:
        """End the carry of part ``obj`` (it was let go)."""
        self.patches[obj] = None
        self.keys[obj] = None
        self.was_in_air[obj], self.set_down[obj] = False, 0
        self.end_put_down(obj)

    def end_put_down(self, obj: int) -> None:
        """Part ``obj`` is no longer held where the hand put it down (``carry_set_down_m``): it follows the hand
        again, or its carry ended."""
        self.still[obj], self.put_down[obj] = 0, False
        self.slide[obj] = 0.0

    def start(self, obj: int, patch: np.ndarray) -> None:
        """Carry part ``obj`` from now on with the hand points ``patch`` (M, 3) around it (camera frame, m)."""
        self.patches[obj] = np.asarray(patch, np.float64)
        self.keys[obj] = self.patches[obj].copy() if self.config.carry_keyframe else None
        self.last_step[obj] = 0.0
        self.last_turn[obj] = 0.0
        self.was_in_air[obj], self.set_down[obj] = False, 0
        self.end_put_down(obj)

    def note_heights(self, heights: np.ndarray, min_height: float) -> None:
        """After the frame's motion decisions: per carried part, whether it has been in the air during this carry and
        for how many frames in a row it has since been set down on the table (``heights``: lowest point above the
        table before this frame's motion, m; ``min_height``: the in-the-air bound, m)."""
        carried = self.carried
        self.was_in_air = carried & (self.was_in_air | (heights > min_height))
        self.set_down = np.where(carried & (heights <= min_height) & self.was_in_air, self.set_down + 1, 0)

    def move_with_camera(self, Rd: np.ndarray, td: np.ndarray) -> None:
        """The camera moved: a point x of the old camera frame is ``Rd @ x + td`` in the new one. The remembered
        positions, hand patches, last steps and turns move with it; the last frame's depth image (a carry's first
        registration takes the hand points from it) cannot be moved, so the motion is kept beside it and the points
        taken from it are moved into the new frame (:meth:`_previous_points`)."""
        self.history = deque((t, pos @ Rd.T + td) for t, pos in self.history)
        for sh in self.shadows:
            if sh is not None:  # the same motion seen from the new camera frame
                sh.t, sh.step = Rd @ sh.t, Rd @ sh.step
                sh.patch = None if sh.patch is None else sh.patch @ Rd.T + td
        self.patches = [None if pts is None else pts @ Rd.T + td for pts in self.patches]
        self.keys = [None if pts is None else pts @ Rd.T + td for pts in self.keys]
        self.last_step = self.last_step @ Rd.T
        self.last_turn = self.last_turn @ Rd.T  # a rotation vector in the camera frame turns with the camera
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = Rd, td
        if self._prev_depth is not None:
            self._prev_motion = T if self._prev_motion is None else T @ self._prev_motion
        for item in self._ring:
            item[1] = T if item[1] is None else T @ item[1]
        self.placed_R = np.einsum("ij,kjl->kil", Rd, self.placed_R)
        self.placed_t = self.placed_t @ Rd.T + td
        self.placed_step = self.placed_step @ Rd.T

    def note_placed(self, placed: np.ndarray, rotations: np.ndarray, positions: np.ndarray) -> None:
        """End of a frame (``carry_backtrack``): the parts ``placed`` (K,) bool by the dense-depth refinement this
        frame, at their final poses (``rotations`` (K, 3, 3) body → camera, ``positions`` (K, 3) m, camera frame),
        are remembered as placed now; the others' placements age by one frame."""
        placed = np.asarray(placed, bool)
        # placed now: the step from its last placement when that was in the previous frame (carry_start_placed_step)
        self.placed_step_ok = np.where(placed, self.placed_age == 0, self.placed_step_ok)
        fresh = placed & (self.placed_age == 0)
        self.placed_step[fresh] = np.asarray(positions, np.float64)[fresh] - self.placed_t[fresh]
        self.placed_age = np.where(self.placed_age >= 0, self.placed_age + 1, -1)
        self.placed_age[placed] = 0
        self.placed_R[placed] = np.asarray(rotations, np.float64)[placed]
        self.placed_t[placed] = np.asarray(positions, np.float64)[placed]

    def move_history(self, Rd: np.ndarray, td: np.ndarray) -> None:
        """The scene moved by ``x ↦ Rd x + td`` (camera frame, m) since the last frame, as the resting parts show it
        (``carry_motion_scene``): the remembered positions of the motion test are moved by it, so that the test
        measures each part's travel against the scene, not the camera's own motion."""
        self.history = deque((t, pos @ Rd.T + td) for t, pos in self.history)

    def _previous_points(self, center: np.ndarray, radius: float, plane, exclude) -> np.ndarray:
        """Hand points around ``center`` in the last frame's depth image, in the current camera frame (the camera's
        motion since that image, :meth:`move_with_camera`, applied: unmoved, a carry's first registration would
        count the camera's motion, already applied to the part, a second time). Arguments in the current frame."""
        return self._points_of(self._prev_depth, self._prev_motion, center, radius, plane, exclude)

    def _points_of(self, depth: np.ndarray, M: np.ndarray | None, center: np.ndarray, radius: float, plane,
                   exclude) -> np.ndarray:
        """Hand points around ``center`` in an earlier ``depth`` image, in the current camera frame; ``M`` (4×4 or
        None: the camera stayed) is the camera's motion since that image (old camera frame → current). Arguments in
        the current frame."""
        if M is None:
            return self._points(depth, center, radius, plane, exclude)
        R, t = M[:3, :3], M[:3, 3]
        old_plane = None if plane is None else (R.T @ plane[0], float(plane[1] + plane[0] @ t))
        old_exclude = [(R.T @ (c - t), r) for c, r in exclude]
        pts = self._points(depth, R.T @ (center - t), radius, old_plane, old_exclude)
        return pts @ R.T + t

    def _backtrack(self, obj: int, plane, exclude, age: int | None = None,
                   start: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """``carry_backtrack``: the hand's motion (x ↦ ``R`` x + ``t``, current camera frame, m) from the frame in
        which the refinement last placed part ``obj`` (1 to ``carry_backtrack`` frames before the previous one) to
        the previous frame, by registering the hand points around the part in each kept depth image to the next
        image's, together with the last of those registrations (rotation vector (rad), translation (m): the next
        registration's first guess); None when that placement is too old, too recent or the hand points too few.
        ``age`` (frames before the previous one) and ``start`` (the part's position then, current camera frame, m)
        replace the placement's (``carry_backtrack_rest_m``)."""
        cfg = self.config
        if age is None:
            age = int(self.placed_age[obj])
        if age < 1 or age > cfg.carry_backtrack or len(self._ring) < age + 1:
            return None
        frames = list(self._ring)[-(age + 1):]
        axis = plane[0] if (plane is not None and cfg.carry_rotation_axis == "table") else None
        R, t = np.eye(3), np.zeros(3)
        p = (self.placed_t[obj] if start is None else np.asarray(start, np.float64)).copy()
        w, step = np.zeros(3), np.zeros(3)
        extra = None  # carry_start_placed_step: the first registration also starts from the placed step
        if cfg.carry_start_placed_step and start is None and self.placed_step_ok[obj]:
            extra = (np.zeros(3), self.placed_step[obj].copy())
        for (d0, M0), (d1, M1) in zip(frames[:-1], frames[1:], strict=True):
            src = self._points_of(d0, M0, p, cfg.carry_radius, plane, exclude)
            dst = self._points_of(d1, M1, p + step, cfg.carry_radius + cfg.carry_max_step, plane, exclude)
            if src.shape[0] < cfg.carry_min_points or dst.shape[0] < cfg.carry_min_points:
                return None
            if cfg.carry_rotation:
                w, step = register_rigid(src, dst, cfg.carry_iterations, cfg.carry_max_step, cfg.carry_max_turn,
                                         (w, step), axis, cfg.carry_turn_fallback, extra, cfg.carry_shift_starts)
                extra = None
            else:
                w, step = np.zeros(3), register_translation(src, dst, cfg.carry_iterations, cfg.carry_max_step, step)
            c = src.mean(axis=0)
            Rw = _rot(w)
            d = c + step - Rw @ c
            R, t, p = Rw @ R, Rw @ t + d, Rw @ p + d
        return R, t, w, step

    def _lookback(self, obj: int, depth: np.ndarray, place: np.ndarray, plane,
                  exclude) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """``carry_lift_lookback``: when fewer than ``carry_min_points`` hand points lie within ``carry_radius`` of
        part ``obj``'s ``place`` (current camera frame, m) in this frame's ``depth`` and in the previous frame's, the
        hand's motion (as :meth:`_backtrack` returns it) from the oldest kept frame, 1 to ``carry_backtrack`` frames
        before the previous one, with that many hand points around the place, to the previous frame; None when the
        place has hand points now or in the previous frame, or no kept frame gives a registration."""
        cfg = self.config
        if self._points(depth, place, cfg.carry_radius, plane, exclude).shape[0] >= cfg.carry_min_points:
            return None
        if self._previous_points(place, cfg.carry_radius, plane, exclude).shape[0] >= cfg.carry_min_points:
            return None
        frames = list(self._ring)
        for age in range(min(cfg.carry_backtrack, len(frames) - 1), 0, -1):
            d0, M0 = frames[-(age + 1)]
            if self._points_of(d0, M0, place, cfg.carry_radius, plane, exclude).shape[0] < cfg.carry_min_points:
                continue
            found = self._backtrack(obj, plane, exclude, age, place)
            if found is not None:
                return found
        return None

    def rest_frame(self, obj: int) -> int | None:
        """``carry_backtrack_rest_m``: how many frames before the previous one part ``obj``'s estimate was last still
        (moved by at most ``carry_backtrack_rest_m`` since the frame before, by the remembered positions), when it has
        moved by more than that in every frame since; None when it did not move in the previous frame, or was not
        still within ``carry_backtrack`` frames (or its positions are not remembered)."""
        cfg = self.config
        h = [pos[obj] for _, pos in self.history]
        for age in range(0, min(cfg.carry_backtrack, len(h) - 2) + 1):
            step = h[-1 - age] - h[-2 - age]
            if not np.all(np.isfinite(step)):
                return None
            if np.linalg.norm(step) <= cfg.carry_backtrack_rest_m:
                return age if age >= 1 else None
        return None

    def forget(self, obj: int) -> None:
        """Drop part ``obj``'s remembered positions (it was re-seeded: the jump is no motion of the part)."""
        for _, pos in self.history:
            pos[obj] = np.nan

    def record(self, now: float, positions: np.ndarray) -> None:
        """Remember the parts' estimated positions (K, 3) at time ``now`` (s) for the motion test."""
        self.history.append((now, np.array(positions, np.float64)))
        while self.history and now - self.history[0][0] > self.config.carry_window_s:
            self.history.popleft()

    def moved(self) -> np.ndarray:
        """Per part, distance (m) travelled between the oldest and the newest remembered positions (0 for a part
        forgotten within the window)."""
        if len(self.history) < 2:
            return np.zeros(len(self.patches))
        return np.nan_to_num(np.linalg.norm(self.history[-1][1] - self.history[0][1], axis=1), nan=0.0)

    def last_step_of(self, obj: int) -> np.ndarray:
        """Part ``obj``'s estimated motion (m) between the two newest remembered positions (zero if unknown)."""
        if len(self.history) < 2:
            return np.zeros(3)
        step = self.history[-1][1][obj] - self.history[-2][1][obj]
        return step if np.all(np.isfinite(step)) else np.zeros(3)

    def in_air(self, obj: int, positions: np.ndarray, heights: np.ndarray) -> bool:
        """Is part ``obj`` above the table by more than carry_min_height with no other part under it?"""
        if not np.isfinite(heights[obj]) or heights[obj] <= self.config.carry_min_height:
            return False
        return not supported_by_other(obj, positions, heights, self.radii)

    def update(self, depth: np.ndarray | None, positions: np.ndarray, hidden: np.ndarray, released: np.ndarray,
               heights: np.ndarray, plane, touched: np.ndarray | None = None,
               rotations: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """One frame. ``positions`` (K, 3) current estimates; ``hidden`` (K,) parts without a reliable blob and
        with a low visible fraction; ``released`` (K,) parts whose blob is reliable again; ``heights`` (K,) lowest
        point above the table (m, inf = unknown); ``touched`` (K,) parts a tracked hand touches (the hand tracker's
        contact test): a hidden touched part is taken to be in that hand like a moving one; ``rotations`` (K, 3, 3)
        the estimates' rotations (body → camera; needed by ``carry_backtrack``). Returns each part's rigid motion
        this frame as rotations (K, 3, 3) and translations (K, 3): a camera-frame point x moves to ``Rd @ x + td``
        (identity and zero when not carried; with ``carry_backtrack`` a starting carry's motion includes the move
        from the estimate to the backtracked pose)."""
        cfg = self.config
        k = len(self.patches)
        rot = np.repeat(np.eye(3)[None], k, axis=0)
        delta = np.zeros((k, 3))
        if depth is None:
            return rot, delta
        moved = self.moved()
        carried = self.carried
        positions = np.array(positions, np.float64)  # a backtracked start moves its part's entry (carry_backtrack)
        self.backtracked = np.zeros(k, bool)
        self._start_guess = {}
        for i in range(k):
            back = None  # carry_backtrack: (R, t) from the estimate to the backtracked pose in the previous frame
            if released[i] or not hidden[i]:
                self.patches[i] = None
                self.keys[i] = None
                self.shadows[i] = None
                continue
            exclude = [(positions[o], self.radii[o] + 0.005) for o in range(k) if o != i and not carried[o]]
            if self.patches[i] is None:
                grasped = touched is not None and bool(touched[i])
                if not (grasped or moved[i] > cfg.carry_min_motion or self.in_air(i, positions, heights)):
                    if cfg.carry_shadow:
                        self._follow_shadow(i, depth, positions[i], plane, exclude)
                    continue
                self.shadows[i] = None
                lifted = moved[i] > cfg.carry_min_motion or self.in_air(i, positions, heights)
                rest_start = cfg.carry_backtrack_rest_m > 0 and (lifted or grasped)
                if (cfg.carry_backtrack > 0 and rotations is not None and self._prev_depth is not depth
                        and (lifted or rest_start)):
                    # from where the refinement last placed it (its placed orientation), or, not placed lately
                    # (hidden at rest under the hand), from where its estimate still rested (its orientation kept)
                    found, p0 = self._backtrack(i, plane, exclude), self.placed_t[i]
                    if found is not None:
                        Rb = found[0] @ self.placed_R[i] @ np.asarray(rotations[i], np.float64).T
                    elif rest_start and (age := self.rest_frame(i)) is not None:
                        p0 = self.history[-1 - age][1][i]
                        found = self._backtrack(i, plane, exclude, age, p0)
                        Rb = None if found is None else found[0]
                    if found is not None:
                        Rh, th, w0, t0 = found
                        p_start = Rh @ p0 + th
                        back = (Rb, p_start - Rb @ positions[i])
                        self.backtracked[i] = True
                        positions[i] = p_start
                if (back is None and grasped and cfg.carry_lift_lookback and cfg.carry_backtrack > 0
                        and self._prev_depth is not None and self._prev_depth is not depth):
                    found = self._lookback(i, depth, positions[i], plane, exclude)
                    if found is not None:  # from its place, moved by the hand's motion since it last covered it
                        Rh, th, w0, t0 = found
                        back = (Rh, th)
                        self.backtracked[i] = True
                        positions[i] = Rh @ positions[i] + th
                prev = None
                if cfg.carry_start_register and self._prev_depth is not None and self._prev_depth is not depth:
                    prev = self._previous_points(positions[i], cfg.carry_radius, plane, exclude)
                if prev is not None and prev.shape[0] >= cfg.carry_min_points:
                    # the hand points around the part in the previous frame, registered to this frame below: the
                    # part moves with the hand from the first frame of the carry, not one frame late
                    self.start(i, prev)
                    self.last_step[i] = self.last_step_of(i)
                    if back is not None:
                        self.last_turn[i], self.last_step[i] = w0, t0
                    elif cfg.carry_start_placed_step and self.placed_step_ok[i] and self.placed_age[i] == 0:
                        # placed in the two previous frames: its step between them, a start the re-seeds left alone
                        self._start_guess[i] = (np.zeros(3), self.placed_step[i].copy())
                else:
                    pts = self._points(depth, positions[i], cfg.carry_radius, plane, exclude)
                    if pts.shape[0] >= cfg.carry_min_points:
                        self.start(i, pts)
                        if back is not None:
                            rot[i], delta[i] = back
                    continue
            # search the current points around where last frame's hand motion would take the part, in a window
            # widened by the largest hand motion per frame
            patch_radius = max(cfg.carry_patch_radius, cfg.carry_radius)  # carry_patch_radius (0: carry_radius)
            pts = self._points(depth, positions[i] + self.last_step[i], patch_radius + cfg.carry_max_step, plane,
                               exclude)
            if patch_radius > cfg.carry_radius:  # whether the hand is still there: carry_radius's window, as without
                n_window = self._points(depth, positions[i] + self.last_step[i], cfg.carry_radius + cfg.carry_max_step,
                                        plane, exclude).shape[0]
            else:
                n_window = pts.shape[0]
            if n_window < cfg.carry_min_points:
                self.patches[i] = None  # the hand left: the part stays where it was put down
                self.keys[i] = None
                continue
            if cfg.carry_rotation:
                axis = plane[0] if (plane is not None and cfg.carry_rotation_axis == "table") else None
                w, t = register_rigid(self.patches[i], pts, cfg.carry_iterations, cfg.carry_max_step,
                                      cfg.carry_max_turn, (self.last_turn[i], self.last_step[i]), axis,
                                      cfg.carry_turn_fallback, self._start_guess.get(i), cfg.carry_shift_starts)
                if cfg.carry_projective > 0 and axis is None:
                    w, t = self._projective(self.patches[i], depth, w, t, plane, exclude)
            else:
                w, t = np.zeros(3), register_translation(self.patches[i], pts, cfg.carry_iterations,
                                                         cfg.carry_max_step, self.last_step[i])
            # the motion about the patch centroid c: x' = Rw (x - c) + c + t
            c = self.patches[i].mean(axis=0)
            Rw = _rot(w)
            rot[i] = Rw
            delta[i] = c + t - Rw @ c
            if cfg.carry_keyframe and self.keys[i] is not None:
                rot[i], delta[i] = self._to_keyframe(i, rot[i], delta[i], pts, plane)
            self.last_step[i], self.last_turn[i] = t, w
            new_pos = Rw @ positions[i] + delta[i]
            if back is not None:  # from the estimate to the backtracked pose, then with the hand to this frame
                rot[i], delta[i] = rot[i] @ back[0], rot[i] @ back[1] + delta[i]
            dist2 = ((pts - new_pos) ** 2).sum(1)
            near = dist2 <= patch_radius**2
            enough = (dist2 <= cfg.carry_radius**2).sum()  # the hand still there: judged within carry_radius
            self.patches[i] = pts[near] if enough >= cfg.carry_min_points else None
            if cfg.carry_keyframe and self.keys[i] is None and self.patches[i] is not None:
                self.keys[i] = self.patches[i].copy()
        if cfg.carry_backtrack > 0 and self._prev_depth is not depth:
            self._ring.append([depth, None])
        self._prev_depth = depth  # kept by reference: a source that reuses its buffer gives the same object (unused)
        self._prev_motion = None
        return rot, delta

    def _projective(self, patch: np.ndarray, depth: np.ndarray, w: np.ndarray, t: np.ndarray, plane,
                    exclude) -> tuple[np.ndarray, np.ndarray]:
        """``carry_projective``: the frame's hand motion (``w`` rad, ``t`` m about ``patch``'s centroid, from the
        nearest-neighbour registration) refined by projective point-to-plane pairing against ``depth``
        (:func:`~tracker.geometry.projective_icp.refine_projective`); kept as it was when the refined motion exceeds
        ``carry_max_step`` or ``carry_max_turn``."""
        cfg = self.config
        w2, t2 = refine_projective(patch, depth, self.intrinsics, w, t, cfg.carry_projective, plane,
                                   cfg.carry_min_height, exclude)
        if np.linalg.norm(w2) > cfg.carry_max_turn or np.linalg.norm(t2) > cfg.carry_max_step:
            return w, t
        return w2, t2

    def _to_keyframe(self, obj: int, R: np.ndarray, d: np.ndarray, pts: np.ndarray,
                     plane) -> tuple[np.ndarray, np.ndarray]:
        """``carry_keyframe``: this frame's hand motion (x ↦ ``R`` x + ``d``, from last frame's patch) corrected by
        registering the carry's keyframe patch, moved by every motion since, to this frame's hand points ``pts``: the
        frame-to-frame registrations' errors do not add up while the hand keeps its shape. When fewer than
        ``carry_keyframe_inliers`` of the keyframe's points then lie within 5 mm of this frame's points (the hand
        changed its grip, or turned other surfaces to the camera) the keyframe starts again from this frame."""
        cfg = self.config
        from scipy.spatial import cKDTree

        key = self.keys[obj] @ R.T + d
        axis = plane[0] if (plane is not None and cfg.carry_rotation_axis == "table") else None
        w2, t2 = register_rigid(key, pts, cfg.carry_iterations, KEY_STEP, KEY_TURN, None, axis)
        c2 = key.mean(axis=0)
        R2 = _rot(w2)
        moved = (key - c2) @ R2.T + c2 + t2
        dist, _ = cKDTree(pts).query(moved, distance_upper_bound=KEY_INLIER)
        if np.isfinite(dist).mean() < cfg.carry_keyframe_inliers:
            self.keys[obj] = None  # taken again from this frame's patch (below)
            return R, d
        self.keys[obj] = moved
        return R2 @ R, R2 @ d + c2 + t2 - R2 @ c2

    def _follow_shadow(self, obj: int, depth: np.ndarray, position: np.ndarray, plane, exclude) -> None:
        """Follow the hand over hidden resting part ``obj`` (at ``position``, camera frame, m) as if it carried the
        part (:class:`Shadow`); started with the hand points around the part, ended (its last motion kept) when the
        hand has gone."""
        cfg = self.config
        sh = self.shadows[obj]
        window = cfg.carry_radius + cfg.carry_max_step  # the same window (and so point density) every frame
        if (cfg.carry_shadow_restart and sh is not None and sh.patch is None
                and np.linalg.norm(sh.t) < self.radii[obj]):
            # carry_shadow_restart: the hand left without the part (a shadow that went less than the part's bounding
            # radius cannot take it, hidden_parts.take_shadow): a hand back over the place starts a new shadow
            sh = None
        if sh is None:
            pts = self._points(depth, position, window, plane, exclude)
            pts = pts[((pts - position) ** 2).sum(1) <= cfg.carry_radius**2]
            if pts.shape[0] >= cfg.carry_min_points:
                self.shadows[obj] = Shadow(pts, np.zeros(3), np.zeros(3))
            return
        if sh.patch is None:
            return
        where = position + sh.t
        pts = self._points(depth, where + sh.step, window, plane, exclude)
        if pts.shape[0] < cfg.carry_min_points:
            sh.patch = None
            return
        src = sh.patch[:: -(-sh.patch.shape[0] // SHADOW_POINTS)]
        t = register_shift(src, pts, SHADOW_ITERATIONS, cfg.carry_max_step, sh.step)
        sh.t, sh.step = sh.t + t, t
        if plane is not None and sh.t @ plane[0] < -0.002:
            # the hand went lower than where it would hold the resting part: it is reaching for it, not holding it
            sh.t = np.zeros(3)
        near = ((pts - (position + sh.t)) ** 2).sum(1) <= cfg.carry_radius**2
        sh.patch = pts[near] if near.sum() >= cfg.carry_min_points else None

    def take_shadow(self, obj: int) -> Shadow | None:
        """Part ``obj``'s shadow (None if none), dropped; its carry starts from the shadow's patch if the hand is
        still there."""
        sh, self.shadows[obj] = self.shadows[obj], None
        if sh is not None and sh.patch is not None:
            self.start(obj, sh.patch)
            self.last_step[obj] = sh.step
        return sh

    def _points(self, depth, center, radius, plane, exclude, max_points: int = 800) -> np.ndarray:
        """Hand points near ``center``, thinned evenly to at most ``max_points`` (keeps the registration cheap)."""
        cfg = self.config
        pts = above_table_points(depth, self.intrinsics, center, radius, plane, cfg.carry_min_height,
                                 cfg.carry_stride, exclude)
        step = -(-pts.shape[0] // max_points)
        return pts[::step] if step > 1 else pts


def carry_over_sliver(trk, obj: int, R: np.ndarray, t: np.ndarray, centroid: np.ndarray | None) -> bool:
    """``carry_over_sliver``: hidden carried part ``obj``, which the colour stage has just re-seeded on the ray of its
    blob's centroid (``centroid``, pixels; its estimate before that in ``trk._pre_reseed``), is put where this
    frame's hand motion (x ↦ ``R`` x + ``t``, camera frame, m) takes its pre-re-seed pose, unless the centroid lies
    farther than ``carry_blob_radii`` projected bounding radii from the centre there (then the blob is right: the
    part is not where the hand took it). A sliver's centroid lies off the part's centre; the hand's motion does not.
    Returns whether it moved the part."""
    from tracker.filter.camera_motion import move_part

    pre = trk._pre_reseed.get(obj)
    if pre is None or centroid is None:
        return False
    R_new, t_new = R @ pre.R, R @ pre.t + t
    c = R_new @ trk.center[obj] + t_new
    if c[2] <= 0.05:
        return False
    uv = trk.intrinsics.project(c[None])[0]
    radius_px = trk._radius[obj] * trk.intrinsics.fx / float(c[2])
    if trk.config.carry_blob_radii > 0 and np.hypot(*(uv - centroid)) > trk.config.carry_blob_radii * radius_px:
        return False
    pre_p = trk._pre_reseed_p.get(obj) if trk.config.carry_sliver_particles else None
    if pre_p is not None:
        # carry_sliver_particles: the re-seed is undone (its particles drawn around the sliver's centroid and the
        # estimate put there) and the hand's motion moves the particles and the estimate from where they were
        trk.p[:, obj] = pre_p
        trk.estimates[trk.names[obj]] = pre
        move_part(trk, obj, R, t)
        return True
    est = trk.estimates[trk.names[obj]]
    Q = R_new @ est.R.T
    move_part(trk, obj, Q, t_new - Q @ est.t)
    return True


def point_normals(pts: np.ndarray, k: int = 8, tree=None) -> np.ndarray:
    """Unit normals (M, 3) of a point set from the covariance of each point's ``k`` nearest neighbours; ``tree``: a
    ``scipy.spatial.cKDTree`` of ``pts`` already built (else one is built)."""
    from scipy.spatial import cKDTree

    k = min(k, pts.shape[0])
    _, idx = (cKDTree(pts) if tree is None else tree).query(pts, k=k)
    near = pts[idx]
    nb = near - near.mean(axis=1, keepdims=True)
    cov = np.einsum("mki,mkj->mij", nb, nb)
    _, vecs = np.linalg.eigh(cov)
    return vecs[:, :, 0]


def supported_by_other(obj: int, positions: np.ndarray, heights: np.ndarray, radii: np.ndarray,
                       margin: float = 0.0) -> bool:
    """Does part ``obj`` rest on (or lean against) another part: one whose lowest point is lower by more than
    ``margin`` (m) and whose centre is within 1.05 × the sum of the bounding radii (``radii``, m)?"""
    for o in range(len(positions)):
        if o == obj:
            continue
        gap = np.linalg.norm(positions[obj] - positions[o])
        if gap < (radii[obj] + radii[o]) * 1.05 and heights[o] < heights[obj] - margin:
            return True
    return False


def register_translation(src: np.ndarray, dst: np.ndarray, iterations: int, max_step: float,
                         guess: np.ndarray | None = None) -> np.ndarray:
    """Translation t (m) that brings point set ``src`` (M, 3) onto ``dst`` (P, 3): point-to-plane ICP (normals of
    ``dst``) over the nearest-neighbour pairs closer than 2 cm, ``iterations`` rounds, started from 0 and from
    ``guess`` (e.g. last frame's motion); the start leaving the smaller mean residual wins. |t| <= ``max_step``.
    Directions the surface does not constrain (a flat patch sliding in its plane) are damped, not guessed."""
    if src.shape[0] < 3 or dst.shape[0] < 3:
        return np.zeros(3)
    from scipy.spatial import cKDTree

    tree = cKDTree(dst)
    normals = point_normals(dst, tree=tree)
    best, best_cost = np.zeros(3), np.inf
    starts = [np.zeros(3)] if guess is None or not np.any(guess) else [np.zeros(3), np.asarray(guess, np.float64)]
    for t in starts:
        for _ in range(max(iterations, 1)):
            d, j = tree.query(src + t, distance_upper_bound=PAIR_BOUND)
            ok = np.isfinite(d)
            if ok.sum() < 3:
                break
            n = normals[j[ok]]
            r = np.einsum("mi,mi->m", n, dst[j[ok]] - (src[ok] + t))
            a = n.T @ n
            a += 1e-3 * np.trace(a) * np.eye(3)
            step = np.linalg.solve(a, n.T @ r)
            t = t + step
            if np.linalg.norm(step) < 5e-5:
                break
        d, _ = tree.query(src + t)
        cost = float(np.mean(np.minimum(d, PAIR_BOUND)))
        if cost < best_cost:
            best, best_cost = t, cost
    norm = float(np.linalg.norm(best))
    return best if norm <= max_step else best * (max_step / norm)


def register_shift(src: np.ndarray, dst: np.ndarray, iterations: int, max_step: float,
                   guess: np.ndarray | None = None) -> np.ndarray:
    """Translation t (m) that brings point set ``src`` (M, 3) onto ``dst`` (P, 3): point-to-point ICP over the
    nearest-neighbour pairs closer than 2 cm, started from ``guess`` (e.g. last frame's motion; else 0), at most
    ``iterations`` rounds; |t| <= ``max_step``. Cheaper than :func:`register_translation` (no normals, one start)."""
    t = np.zeros(3) if guess is None else np.asarray(guess, np.float64).copy()
    if src.shape[0] < 3 or dst.shape[0] < 3:
        return np.zeros(3)
    from scipy.spatial import cKDTree

    tree = cKDTree(dst)
    for _ in range(max(iterations, 1)):
        d, j = tree.query(src + t, distance_upper_bound=PAIR_BOUND)
        ok = np.isfinite(d)
        if ok.sum() < 3:
            break
        step = (dst[j[ok]] - src[ok] - t).mean(axis=0)
        t = t + step
        if np.linalg.norm(step) < 5e-5:
            break
    norm = float(np.linalg.norm(t))
    return t if norm <= max_step else t * (max_step / norm)


def register_rigid(src: np.ndarray, dst: np.ndarray, iterations: int, max_step: float, max_turn: float,
                   guess: tuple[np.ndarray, np.ndarray] | None = None,
                   axis: np.ndarray | None = None, turn_fallback: bool = False,
                   extra: tuple[np.ndarray, np.ndarray] | None = None,
                   shift: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Rigid motion that brings point set ``src`` (M, 3) onto ``dst`` (P, 3): rotation vector ``w`` (rad) about
    ``src``'s centroid c and translation ``t`` (m), i.e. x' = R(w) (x − c) + c + t. Point-to-plane ICP (normals of
    ``dst``) over nearest-neighbour pairs closer than 2 cm, ``iterations`` Gauss-Newton rounds, started from no
    motion and from ``guess`` (last frame's (w, t)); the start leaving the smaller mean residual wins.

    The rotation is damped (Tikhonov, 1e-2 of the mean translational information, in units of the patch's radius)
    so that rotations the surface does not constrain (a cylinder-like forearm about its axis) stay near zero, and
    capped at ``max_turn`` rad (with ``turn_fallback`` a larger turn is taken as a failed registration and the
    translation-only registration is returned instead); |t| <= ``max_step``. With ``axis`` (unit, camera frame;
    e.g. the table normal) the rotation is about that axis only. ``extra`` (w, t): a third start
    (``carry_start_placed_step``); when it wins, the translation-only fallback starts from its translation too.
    ``shift`` (m, ``carry_shift_starts``; 0 = none): more starts, :func:`shifted_starts`, taken only when one leaves a
    mean residual lower than the usual starts' best by more than ``SHIFT_MARGIN``."""
    zero = (np.zeros(3), np.zeros(3))
    if src.shape[0] < 6 or dst.shape[0] < 6:
        return zero
    from scipy.spatial import cKDTree

    dst = np.ascontiguousarray(dst, np.float64)
    normals = np.ascontiguousarray(point_normals(dst, tree=cKDTree(dst)))
    c = src.mean(axis=0)
    rel = np.ascontiguousarray(src - c, np.float64)
    radius2 = max(float((rel**2).sum(1).mean()), 1e-6)
    # grid cells no smaller than the pairing bound (exact nearest neighbour within it), at most ~64 per side
    cell = max(PAIR_BOUND, float(np.ptp(dst, axis=0).max()) / 64.0)
    grid = build_grid(dst, cell)
    use_axis = axis is not None
    ax = np.asarray(axis, np.float64).reshape(3) if use_axis else np.zeros(3)
    starts = [zero]
    if guess is not None and (np.any(guess[0]) or np.any(guess[1])):
        starts.append((np.asarray(guess[0], np.float64), np.asarray(guess[1], np.float64)))
    if extra is not None:
        starts.append((np.asarray(extra[0], np.float64), np.asarray(extra[1], np.float64)))
    best, best_cost, won = zero, np.inf, 0
    for s, (w, t) in enumerate(starts):
        w, t, cost = rigid_icp(rel, c, dst, normals, *grid, cell, PAIR_BOUND, np.array(w, np.float64).reshape(3),
                               np.array(t, np.float64).reshape(3), int(iterations), radius2, ax, use_axis)
        if cost < best_cost:
            best, best_cost, won = (w, t), cost, s
    if shift > 0:
        bar = best_cost - SHIFT_MARGIN
        for w, t in shifted_starts(starts, shift):
            w, t, cost = rigid_icp(rel, c, dst, normals, *grid, cell, PAIR_BOUND, w, t, int(iterations), radius2, ax,
                                   use_axis)
            if cost < bar:
                best, bar, won = (w, t), cost, -1  # the fallback then starts from no motion's and the guess's
    w, t = best
    th, norm = float(np.linalg.norm(w)), float(np.linalg.norm(t))
    if th > max_turn:
        if turn_fallback:
            # a turn beyond what a hand does in one frame is the registration failing (pairs mismatched by a fast
            # move, the rotation absorbing the rest): the translation alone is taken
            t0 = extra[1] if (extra is not None and won == len(starts) - 1) else (guess[1] if guess else None)
            if won < 0:  # a shifted start won (carry_shift_starts): the translation-only registration from its step
                t0 = t
            return np.zeros(3), register_translation(src, dst, iterations, max_step, t0)
        w = w * (max_turn / th)
    if norm > max_step:
        t = t * (max_step / norm)
    return w, t


SHIFT_MARGIN = 0.001
"""How much (m) lower a shifted start's mean residual must be than the usual starts' best to be taken
(``carry_shift_starts``): a healthy hand-patch registration leaves 1.5-3 mm, a wrong minimum 6-9 mm on the tuning
traces; a start that only lands in the same minimum a hair lower does not replace it."""


def shifted_starts(starts: list[tuple[np.ndarray, np.ndarray]], shift: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """``carry_shift_starts``: the registration's usual starts (w rad, t m; no motion first, then the guesses) each
    moved by ``shift`` m along +x, −x, +y, −y, +z, −z of the camera frame (rotations kept): with a hand step beyond
    the 2 cm pairing bound one of them lies within it of the true step."""
    out = []
    for w, t in starts:
        for a in range(3):
            for sign in (1.0, -1.0):
                t2 = np.array(t, np.float64).reshape(3).copy()
                t2[a] += sign * shift
                out.append((np.array(w, np.float64).reshape(3).copy(), t2))
    return out


def warm_up() -> None:
    """Load (or compile) the numba kernels of the hand-patch points and registrations (:func:`above_table_points`,
    :func:`register_rigid`, ``carry_projective``'s :func:`refine_projective`) on tiny inputs of the types the carry
    passes them, so that a session's first carry does not pay for it."""
    depth = np.full((8, 8), 0.5, np.float32)
    intr = Intrinsics(8, 8, 10.0, 10.0, 4.0, 4.0)
    above_table_points(depth, intr, np.array([0.0, 0.0, 0.5]), 0.1, (np.array([0.0, 0.0, -1.0]), 0.6), 0.0, 1,
                       [(np.array([0.0, 0.0, 0.4]), 0.01)])
    g = np.linspace(-0.02, 0.02, 3)
    pts = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3) + np.array([0.0, 0.0, 0.5])
    register_rigid(pts, pts + 0.001, 2, 0.01, 0.1)
    projective_icp.warm_up()


def _rot(w: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of one rotation vector (rad)."""
    return rotvec_to_matrix(w)[0]
