"""``EgoMotion``: the camera odometry as a stage of the tracker (issue 15 item 3).

Per frame, before the particle filter's step:

1. **Mask** what must not define the camera's motion (True = exclude, :func:`moving_scene_mask`): everything that
   stands out of the table plane (``FOREGROUND_MIN_M`` … ``FOREGROUND_MAX_M`` above it: hands, arms, parts) except
   the silhouettes of the parts that stay put in the world frame (static parts carry texture and geometry the
   odometry needs: the simulated table's grain leaves translation along the planks nearly unobserved); the
   silhouettes of moving parts (carried, under a hand box, or shifted by more than ``MOVING_MIN_M`` in the world
   frame within ``MOVING_WINDOW_S``); and hand boxes when a source or a hand tracker gives them
   (:func:`frame_hand_boxes`).
2. **Odometry step** (:func:`tracker.odometry.make_odometry`): the camera's pose ``T_wc`` in the world frame (=
   the first frame's camera frame; camera → world, metres).
3. **Camera motion** for the tracker: ``T_new_old = T_wc⁻¹ · T_applied`` where ``T_applied`` is the camera pose
   the tracker's camera-frame state refers to. It is returned (to be applied with
   :func:`tracker.filter.camera_motion.apply_camera_motion`) only when the step was measured and the motion exceeds
   a dead band (``DEADBAND_M`` / ``DEADBAND_DEG``; below it the jitter of the estimate would only shake the
   parts). A failed step (no depth, failed or implausible alignment) returns none: the tracker keeps its
   camera-frame prediction (as with odometry off), the caller re-checks the table plane, and the next measured
   step starts again from its own pose (the motion during the failure is left to the filter). A motion larger
   than ``MAX_STEP_M`` / ``MAX_STEP_DEG`` between consecutive frames is taken for a jump of the odometry and
   handled the same way (counted in ``jumps``).
4. **Table plane**: once anchored (:meth:`anchor_table`, the plane detected in the current camera frame is stored
   in the world frame) it is propagated into the new camera frame (:meth:`table_in_camera`) instead of being
   re-detected on every frame that applies a camera motion (``moved``). A frame that applies none (idle, inside the
   dead band, a restart) leaves the tracker's camera frame where it was, so the caller keeps its plane and checks it
   as with odometry off: with a fixed camera the tracker then sees exactly the planes it sees with odometry off.
5. **Idle while the camera is still**: after ``STILL_FRAMES`` measured frames in a row inside the dead band, the
   mask and the odometry are skipped and each frame only compares a coarse depth grid (every ``IDLE_GRID_PX``-th
   pixel) with the grid of the frame the camera came to rest in (:data:`IDLE_CHANGE_M`); the pose stays, nothing
   is applied, the step counts as measured. When the depth has changed, the odometry runs again on that frame:
   it aligns to its keyframe, so the motion since the rest is measured whole and applied at once. A camera drifting
   slowly along the table changes the depth too little for that test (a sway near its turning point: 3–5 mm before
   it woke on tuning seeds); with ``idle_check`` > 0 every ``idle_check``-th idle frame also runs the mask and the
   odometry and wakes when the pose has moved by more than ``IDLE_WAKE_M`` / ``IDLE_WAKE_DEG`` (else it stays idle:
   nothing applied, nothing observed). It is off by default (:data:`IDLE_CHECK_FRAMES`). With
   ``fused`` the smooth path stands still while idle (no velocity, its clock moving on) and takes the wake frame's
   dense pose as it comes: it is the motion since the rest, not one frame's. A fixed camera then costs about a
   millisecond per frame instead of the full stage. A camera that applied a motion less than ``IDLE_AFTER_MOTION_S``
   ago does not idle (a sway's turning point is not a rest).
"""

from __future__ import annotations

import dataclasses
import time
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from tracker.frame import Frame
from tracker.geometry.camera import Intrinsics
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose
from tracker.odometry.exclusion_mask import PART_MARGIN_PX
from tracker.odometry.foreground import enlarge_twice, fill_large_blobs, foreground
from tracker.odometry.se3 import invert, motion_size

FOREGROUND_MIN_M = 0.012
"""Metres above the table plane from which a pixel is foreground (hand, arm, part) rather than table."""
FOREGROUND_MAX_M = 0.40
"""Metres above the table plane up to which a pixel is foreground (higher: background such as a wall)."""
FOREGROUND_BOX_MIN_PX = 2000
"""A foreground blob of at least this many pixels (a hand, an arm: larger than a part) is excluded with its whole
bounding box: the box also covers the shadow it casts on the table, which moves with it and misled the photometric
term (a 3 cm jump on tuning seed 1 with only the blob masked)."""
MOVING_MIN_M = 0.004
"""A part whose world-frame position changed by more than this (metres) within ``MOVING_WINDOW_S`` is moving."""
MOVING_WINDOW_S = 0.5
"""Seconds of world-frame part positions remembered for the moving test."""
DEADBAND_M = 0.0003
"""Camera motions smaller than this translation (metres) and ``DEADBAND_DEG`` are not applied to the tracker."""
DEADBAND_DEG = 0.03
"""Rotation dead band of the applied camera motion, degrees."""
MAX_STEP_M = 0.008
"""A camera motion between consecutive frames larger than this (metres) or ``MAX_STEP_DEG`` is taken for a jump of
the odometry (a wrong registration: 3–8 cm in one frame on tuning seeds 1 and 2 while an arm covered the parts), not
for the camera's motion: it is not applied, and the tracker and the table plane are re-anchored to the new pose.
The tracker needs only the frame-to-frame motion, so an offset the odometry keeps after a jump does no harm."""
MAX_STEP_DEG = 1.5
"""Rotation bound of :data:`MAX_STEP_M`, degrees."""
IDLE_AFTER_MOTION_S = 3.0
"""Default ``idle_after_motion_s`` of :class:`EgoMotion`: the odometry idles only once this many seconds have passed
since it last applied a camera motion (0: no such wait). A swaying camera slows to a stop at its turning points for
``STILL_FRAMES`` and more; idling there left the sway's next slow slide to the depth test, which missed 10 mm of it
on a tuning session (guidance-demo sway, seed 1), the hidden parts left that far off, and the wake frame's motion was
then over ``MAX_STEP_M`` and discarded as a jump. A fixed camera applies no motion and idles as before. Tuning
seeds, the ten moving-camera sessions of the held-out design, tracker seed 0, paired (session 22): bad part-frames
300 → 287 / 459 → 459 / 642 → 631 on sets 1 / 2 / 3, parts lost equal; fixed-camera sessions unchanged."""
STILL_FRAMES = 10
"""After this many measured frames in a row whose camera motion stays inside the dead band, the odometry idles
(step 5 of the module docstring)."""
IDLE_CHECK_FRAMES = 0
"""Default ``idle_check`` of :class:`EgoMotion`: while idle, every this many frames the odometry runs anyway and wakes
when the camera has moved by more than ``IDLE_WAKE_M`` / ``IDLE_WAKE_DEG`` since the rest (module docstring, step 5);
0 = never. Off: on a fixed camera (tuning seed 3 of guess-1) a check with a hand in view registered wrongly by over
1 mm, woke the odometry, and 2 mm of motion were then applied to a camera that never moved."""
IDLE_WAKE_M = 0.001
"""Translation (metres) since the rest that the idle check takes for a motion; more than the dead band, which the
dense step's jitter with a hand in view left often enough to keep a fixed camera awake half the time (tuning seed 3
of guess-1, fixed camera)."""
IDLE_WAKE_DEG = 0.1
"""Rotation bound of :data:`IDLE_WAKE_M`, degrees."""
IDLE_GRID_PX = 8
"""Pixel step of the depth grid the idle test compares (80×60 samples at 640×480)."""
IDLE_CHANGE_M = 0.0015
"""The idle test wakes the odometry when the median absolute depth change of the grid since the camera came to rest
exceeds this (metres) or twice the median change between two frames at rest (the sensor's noise), whichever is
larger. A part or a hand moving over the table changes less than half of the grid and leaves the median alone; a
camera that moves by a millimetre or two changes nearly every table pixel."""
MODES = ("default", "fastslam", "fused", "off")
"""Values of the ``--odometry`` option: an odometry method of :data:`tracker.odometry.METHODS`, ``fused`` (the dense
odometry checked by the tracker's resting parts, :mod:`tracker.odometry.fused_odometry`) or ``off``."""
DEFAULT_MODE = "fused"
"""The odometry of ``track`` and ``serve`` unless told otherwise (the pipeline and ``TrackSession`` are given it). On
a fixed camera it idles (step 5 of the module docstring) and gives the same poses as ``off`` (tuning seeds, 12
fixed-camera sessions: equal poses, about 1 ms more CPU per frame); with a swaying or hand-held camera it beat
``off`` on both tuning sets (10 moving-camera sessions each: 336 against 422 and 631 against 798 bad part-frames, 0
against 1 and 1 against 1 parts lost; session 17)."""


@dataclass(frozen=True)
class EgoMotionStep:
    """One frame of :class:`EgoMotion`.

    * ``pose_world_camera``: camera → world (world = first camera frame), measured or extrapolated;
    * ``ok``: the pose was measured (False: extrapolated; ``message`` says why);
    * ``camera_motion``: 4×4 ``T_new_old`` to apply to the tracker's camera-frame state, or None (nothing to apply);
    * ``ms``: wall time of the stage (mask + odometry), milliseconds.
    """

    pose_world_camera: Pose
    ok: bool
    camera_motion: np.ndarray | None
    ms: float
    message: str = ""


def frame_hand_boxes(frame: Frame, extra: Iterable[Sequence[int] | None] = ()) -> list[list[int]]:
    """Pixel boxes ``[u0, v0, u1, v1]`` (end-exclusive) of the hands known for ``frame``, for :meth:`EgoMotion.step`:
    those a source or a hand tracker put in ``frame.meta["hand_boxes"]``, then ``extra`` (e.g. a hand tracker's
    latest boxes). None entries and empty boxes are dropped."""
    out = []
    for box in [*(frame.meta.get("hand_boxes") or []), *extra]:
        if box is None:
            continue
        u0, v0, u1, v1 = (int(round(float(x))) for x in box)
        if u1 > u0 and v1 > v0:
            out.append([u0, v0, u1, v1])
    return out


def part_silhouettes(shape: tuple[int, int], intrinsics: Intrinsics, parts: Sequence[PartSpec],
                     poses: Mapping[str, Pose], names: Iterable[str]) -> np.ndarray:
    """H×W uint8 mask (1 inside) of the convex hulls of the named parts' projected vertices (camera-frame poses)."""
    h, w = shape
    out = np.zeros((h, w), np.uint8)
    by_name = {p.name: p for p in parts}
    for name in names:
        pose, part = poses.get(name), by_name.get(name)
        if pose is None or part is None:
            continue
        pts = pose.transform_points(_hull_vertices(part))
        if (pts[:, 2] <= 1e-3).any():
            continue
        uv = intrinsics.project(pts)
        if not np.isfinite(uv).all():
            continue
        hull = cv2.convexHull(np.round(uv).astype(np.int32))
        cv2.fillConvexPoly(out, hull, 1)
    return out


_HULLS: dict[int | tuple, np.ndarray] = {}


def _hull_vertices(part: PartSpec) -> np.ndarray:
    """The part's body-frame vertices (a box's 8 corners; a mesh's convex-hull vertices), cached (boxes by their
    size; read only)."""
    if part.box is not None:
        key = ("box", *(float(x) for x in part.box))
        if key not in _HULLS:
            _HULLS[key] = part.vertices()
        return _HULLS[key]
    key = id(part)
    if key not in _HULLS:
        import trimesh

        mesh = part.load_mesh()
        _HULLS[key] = np.asarray(trimesh.Trimesh(mesh.vertices, mesh.faces).convex_hull.vertices, np.float64)
    return _HULLS[key]


def foreground_above(depth: np.ndarray, intrinsics: Intrinsics, table, static: np.ndarray) -> np.ndarray:
    """H×W uint8 mask (1 = foreground): pixels of ``depth`` (metres) between ``FOREGROUND_MIN_M`` and
    ``FOREGROUND_MAX_M`` above ``table`` (a plane with ``normal`` and ``offset`` in the camera frame) outside the
    ``static`` silhouettes (uint8 or bool, 1 inside)."""
    h, w = static.shape
    n = np.asarray(table.normal, np.float32)
    rx = (np.arange(w, dtype=np.float32) - np.float32(intrinsics.cx)) / np.float32(intrinsics.fx)
    ry = (np.arange(h, dtype=np.float32) - np.float32(intrinsics.cy)) / np.float32(intrinsics.fy)
    return foreground(np.asarray(depth, np.float32), rx, ry, n, np.float32(table.offset),
                      np.ascontiguousarray(static, np.uint8), np.float32(FOREGROUND_MIN_M),
                      np.float32(FOREGROUND_MAX_M))


def moving_scene_mask(depth: np.ndarray | None, intrinsics: Intrinsics, table, static: np.ndarray,
                      moving: np.ndarray, hand_boxes: Iterable[Sequence[int]] = (),
                      margin: int = PART_MARGIN_PX, min_box_px: int = FOREGROUND_BOX_MIN_PX,
                      fg: np.ndarray | None = None) -> np.ndarray:
    """H×W bool mask, True = exclude from the odometry: foreground above ``table`` (a plane with ``normal`` and
    ``offset`` in the camera frame, or None) outside the ``static`` silhouettes (:func:`foreground_above`, or ``fg``
    when given: it is changed in place) — with the bounding box of every foreground blob of at least ``min_box_px``
    pixels —, the ``moving`` silhouettes and the hand boxes ``[u0, v0, u1, v1]`` (end-exclusive), dilated by
    ``margin`` pixels. ``depth`` (metres), ``intrinsics``, the silhouettes and the boxes are all of one image size
    (the full frame's or a reduced one's)."""
    h, w = static.shape
    out = moving.astype(np.uint8, copy=True)
    if fg is None and table is not None and depth is not None:
        fg = foreground_above(depth, intrinsics, table, static)
    if fg is not None:
        if min_box_px > 0:
            n_blobs, labels = cv2.connectedComponents(fg, connectivity=8, ltype=cv2.CV_32S)
            fill_large_blobs(fg, labels, n_blobs, int(min_box_px))
        out |= fg
    if margin > 0 and out.any():
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1, 2 * margin + 1))
        out = cv2.dilate(out, k)
    for box in hand_boxes:
        u0, v0, u1, v1 = (int(x) for x in box)
        out[max(0, v0 - margin):min(h, v1 + margin), max(0, u0 - margin):min(w, u1 + margin)] = 1
    return out.astype(bool)


class EgoMotion:
    """Camera ego-motion for a tracker (see the module docstring).

    ``method``: ``default`` (dense RGB-D odometry), ``fastslam`` or ``fused``; ``intrinsics`` of the frames;
    ``parts``: the tracked parts (for their silhouettes); ``idle``: skip the odometry while the camera is at rest
    (step 5 of the module docstring); ``idle_check``: while idle, run the odometry every this many frames to check
    the rest (0: never); ``plane_mask_foreground``: see the attribute."""

    def __init__(self, method: str, intrinsics: Intrinsics, parts: Sequence[PartSpec], seed: int = 0,
                 idle: bool = True, idle_check: int = IDLE_CHECK_FRAMES,
                 idle_after_motion_s: float = IDLE_AFTER_MOTION_S) -> None:
        from tracker.odometry import OdometryConfig, make_odometry

        self.method = method
        self.idle = bool(idle)
        self.idle_check = int(idle_check)
        self.idle_after_motion_s = float(idle_after_motion_s)
        self.plane_mask_foreground = False
        """``fused``: measure the table plane outside the odometry's whole mask, with the boxes of the foreground blobs
        (True, before session 23), or outside the parts' silhouettes, the hand boxes and the foreground pixels
        themselves, dilated (False): the blob boxes flicker with the depth noise at a real scene's clutter (a book, a
        keyboard), and every change of the table pixels they leave tilted the plane fitted to a real, not perfectly
        flat desk by up to 0.5°, which was taken for a camera motion. On the simulator's flat table the plane measured
        either way is as close to the true one (median 0.003° / 0.02 mm, tuning session)."""
        self.intrinsics = intrinsics
        self.parts = list(parts)
        self.odometry = make_odometry("default" if method == "fused" else method, intrinsics, seed=seed,
                                      config=OdometryConfig.fast() if method == "fused" else
                                      OdometryConfig.half_resolution() if method == "default" else None)
        self.fused = None
        self.reset()

    def reset(self) -> None:
        """Forget the camera's path: the next frame defines the world frame again."""
        self.odometry.reset()
        if self.method == "fused":
            from tracker.odometry.fused_odometry import FusedOdometry

            self.fused = FusedOdometry()
        self.pose = Pose()
        self.ok = True
        self._applied: np.ndarray | None = None  # camera pose the tracker's state refers to (None: none yet)
        self._table_world = None  # (normal, offset, plane) of the anchored table, world frame
        self._history: deque[tuple[float, dict[str, np.ndarray]]] = deque()
        self.failures = 0
        self.jumps = 0
        self._observe_pending = False
        self._plane = None  # fused: the table plane measured in the frame of step() (camera frame)
        self.last_mask: np.ndarray | None = None
        self.plane_mask: np.ndarray | None = None  # fused: what the table plane's measurement excludes (True)
        self._still = 0  # measured frames in a row inside the dead band
        self._grid: np.ndarray | None = None  # the last measured frame's depth grid (idle test)
        self._rest: tuple[np.ndarray, float] | None = None  # idle: (depth grid at rest, change threshold m)
        self._idle_count = 0  # idle frames since the rest began (every idle_check-th runs the odometry)
        self.idle_frames = 0
        self.idle_checks = 0  # idle frames on which the odometry ran to check the rest
        self.moved = False  # the last step applied a camera motion (the table plane is to be propagated)
        self._last_motion_t = -np.inf  # timestamp (s) of the last frame that applied a camera motion

    # ------------------------------------------------------------------------------------------- per frame
    def moving_parts(self, poses: Mapping[str, Pose], carried: Iterable[str] = (),
                     hand_boxes: Sequence[Sequence[int]] = ()) -> set[str]:
        """Parts taken to move in the world frame: ``carried``, those whose projected centre lies in a hand box
        (grown by 30 px), and those that moved by more than ``MOVING_MIN_M`` within ``MOVING_WINDOW_S``."""
        moving = set(carried)
        for name, pose in poses.items() if hand_boxes else ():
            if pose.t[2] > 1e-3:
                u, v = self.intrinsics.project(pose.t[None])[0]
                if any(b[0] - 30 <= u < b[2] + 30 and b[1] - 30 <= v < b[3] + 30 for b in hand_boxes):
                    moving.add(name)
        now = self._history[-1][1] if self._history else {}
        # (every remembered frame's positions against now's in one array operation instead of one per frame: the
        # same differences and distances)
        names, cur, past_pos = [], [], []
        for _, past in list(self._history)[:-1]:
            for n, p in now.items():
                q = past.get(n)
                if q is not None:
                    names.append(n)
                    cur.append(p)
                    past_pos.append(q)
        if names:
            d = np.array(cur) - np.array(past_pos)
            far = np.sqrt(np.sum(d * d, axis=1)) > MOVING_MIN_M
            moving.update(n for n, f in zip(names, far.tolist(), strict=True) if f)
        return moving

    def step(self, frame: Frame, table=None, poses: Mapping[str, Pose] | None = None, carried: Iterable[str] = (),
             hand_boxes: Sequence[Sequence[int]] = ()) -> EgoMotionStep:
        """One frame: mask, odometry, the camera motion to apply. ``table``: the current plane (camera frame of
        the previous frame; None before one is found); ``poses``: the parts' latest camera-frame estimates;
        ``carried``: parts held in a hand; ``hand_boxes``: pixel boxes of hands."""
        t0 = time.perf_counter()
        poses = dict(poses or {})
        hand_boxes = [b for b in hand_boxes if b is not None]
        self.moved = False
        now = float(frame.timestamp)
        checking = woken = False
        if self.idle and self._rest is not None:
            if self._still_at_rest(frame):
                self._idle_count += 1
                if self.idle_check <= 0 or self._idle_count % self.idle_check:
                    return self._idle_step(now, poses, t0)
                checking = True  # the depth looks the same: check with the odometry every few idle frames
            else:
                woken = True
        moving = self.moving_parts(poses, carried, hand_boxes)
        mask = self._mask(frame, table, poses, moving, hand_boxes)
        self.last_mask = mask
        if self.fused is not None:  # the dense odometry starts from the fused path (fused_odometry.dense_prior)
            res = self.odometry.step(frame, mask, prior=self.fused.dense_prior(now))
        else:
            res = self.odometry.step(frame, mask)
        if checking:
            self.idle_checks += 1
            if res.ok and self._at_rest(res.pose_world_camera):
                return self._idle_step(now, poses, t0)
            self._rest, self._still, woken = None, 0, True  # the camera has moved: wake
        self.pose, self.ok = res.pose_world_camera, bool(res.ok)
        self._plane = None
        if self.fused is not None and res.ok:  # the dense pose checked against the smooth path (parts: observe())
            self.pose = self.fused.predict(now, res.pose_world_camera, since_rest=woken)
            guess = None if table is None else (table.normal, table.offset)
            plane_mask = mask if self.plane_mask is None else self.plane_mask
            self._plane = self.fused.measure_table(frame.depth, self.intrinsics, plane_mask, guess=guess)
            self._observe_pending = True
        elif self.fused is not None and self.fused.pose_world_camera is not None:
            # no dense pose: the fused path's prediction, corrected by the resting parts in observe(); the tracker
            # keeps its camera-frame prediction this frame (nothing applied) as with the other methods
            self.pose = self.fused.predict(now, None)
            self._observe_pending = True
        T_wc = self.pose.as_matrix()
        motion = None
        if not res.ok:
            self.failures += 1
            self._applied = None
        elif self._applied is None:  # first measured pose (after a failure): the tracker's frame is this camera's
            self._restart(T_wc, table)
        else:
            D = invert(T_wc) @ self._applied
            dt, dr = motion_size(D)
            if dt > MAX_STEP_M or np.degrees(dr) > MAX_STEP_DEG:
                self.jumps += 1
                self._restart(T_wc, table)
            elif dt > DEADBAND_M or np.degrees(dr) > DEADBAND_DEG:
                motion = D
                self._applied = T_wc
            else:
                self._count_still(frame, now)
        self.moved = motion is not None
        if motion is not None:
            self._last_motion_t = now
        if motion is not None or not res.ok:
            self._still = 0
        self._remember(float(frame.timestamp), poses, motion)
        return EgoMotionStep(self.pose, bool(res.ok), motion, 1e3 * (time.perf_counter() - t0), res.message)

    def _idle_step(self, now: float, poses: Mapping[str, Pose], t0: float) -> EgoMotionStep:
        """An idle frame: the pose stays, nothing is applied; ``fused``'s smooth path stands still."""
        self.idle_frames += 1
        if self.fused is not None:
            self.fused.hold(now)
        self._remember(now, poses, None)
        return EgoMotionStep(self.pose, True, None, 1e3 * (time.perf_counter() - t0), "camera at rest: idle")

    def _at_rest(self, dense: Pose) -> bool:
        """Idle check: does the odometry's pose ``dense`` (its own world frame) stay within ``IDLE_WAKE_M`` /
        ``IDLE_WAKE_DEG`` of the pose the tracker's state refers to?"""
        if self._applied is None:
            return False
        T = dense.as_matrix() if self.fused is None else self.fused.from_dense(dense)
        dt, dr = motion_size(invert(T) @ self._applied)
        return dt <= IDLE_WAKE_M and np.degrees(dr) <= IDLE_WAKE_DEG

    def _depth_grid(self, frame: Frame) -> np.ndarray | None:
        return None if frame.depth is None else np.array(frame.depth[::IDLE_GRID_PX, ::IDLE_GRID_PX], np.float32)

    def _count_still(self, frame: Frame, now: float) -> None:
        """A measured frame inside the dead band at ``now`` (s): after ``STILL_FRAMES`` of them, and
        ``idle_after_motion_s`` after the last applied camera motion, the odometry idles (the grid at rest and the
        change threshold from the change since the last such frame are kept)."""
        self._still += 1
        grid, last = self._depth_grid(frame), self._grid
        self._grid = grid
        if self._still < STILL_FRAMES or grid is None or last is None or not self.idle:
            return
        if now - self._last_motion_t < self.idle_after_motion_s:
            return  # a camera that was moving a moment ago (a sway at its turning point) is not taken to rest
        noise = _median_change(grid, last)
        if noise is not None:
            self._rest = (grid, max(IDLE_CHANGE_M, 2.0 * noise))
            self._idle_count = 0

    def _still_at_rest(self, frame: Frame) -> bool:
        """Idle test (step 5 of the module docstring): is the camera still where it came to rest? False wakes the
        odometry (and ends the rest)."""
        if self._rest is None:
            return False
        grid = self._depth_grid(frame)
        change = None if grid is None else _median_change(grid, self._rest[0])
        if change is not None and change <= self._rest[1]:
            return True
        self._rest = None
        self._still = 0
        return False

    def _mask(self, frame: Frame, table, poses: Mapping[str, Pose], moving: set[str],
              hand_boxes: Sequence[Sequence[int]]) -> np.ndarray:
        """The exclusion mask of :func:`moving_scene_mask` (full frame size, True = exclude), worked out at half
        resolution (every other pixel of the depth; margins and blob sizes halved) and enlarged: the dense odometry
        uses the half-resolution level and coarser only (:class:`~tracker.odometry.odometry_config.OdometryConfig`),
        and the full-resolution mask cost about 3 ms of the stage's CPU time per frame."""
        h, w = frame.color.shape[:2]
        if h < 4 or w < 4:
            raise ValueError(f"frame {frame.index}: image {w}x{h} too small for the odometry")
        half = (h // 2, w // 2)
        intr = self.intrinsics.scaled(0.5)
        static = part_silhouettes(half, intr, self.parts, poses, set(poses) - moving)
        moving_sil = part_silhouettes(half, intr, self.parts, poses, moving)
        depth = None if frame.depth is None else frame.depth[: 2 * half[0]:2, : 2 * half[1]:2]
        boxes = [[b[0] // 2, b[1] // 2, -(-b[2] // 2), -(-b[3] // 2)] for b in hand_boxes]
        fg = None if table is None or depth is None else foreground_above(depth, intr, table, static)
        self.plane_mask = None
        if self.fused is not None and not self.plane_mask_foreground:
            # the table's measurement: the parts, the hands and the foreground pixels themselves, not the blobs' boxes
            plane = static | moving_sil if fg is None else static | moving_sil | fg
            self.plane_mask = _full_size(moving_scene_mask(None, intr, None, static, plane, boxes,
                                                           margin=-(-PART_MARGIN_PX // 2)), h, w)
        small = moving_scene_mask(depth, intr, table, static, moving_sil, boxes, margin=-(-PART_MARGIN_PX // 2),
                                  min_box_px=FOREGROUND_BOX_MIN_PX // 4, fg=fg)
        return _full_size(small, h, w)

    @property
    def correction_pending(self) -> bool:
        """``fused``: the odometry measured this frame and :meth:`observe` will correct the camera after the
        tracker's step (False when it idles: the hidden parts are then left to scene motion, as with odometry off)."""
        return self.fused is not None and self._observe_pending

    def observe(self, landmarks: Mapping[str, Pose], corners: Mapping[str, np.ndarray]) -> np.ndarray | None:
        """``fused`` only, after the tracker's step on the frame of :meth:`step`: its resting parts seen well
        (``landmarks``, part → camera poses; ``corners`` body-frame corner points per part, metres) correct the
        camera's world pose (:meth:`tracker.odometry.fused_odometry.FusedOdometry.correct`).

        Returns the correction for the tracker's camera-frame state (4×4 ``T_new_old``, the frame the state refers
        to → the corrected camera's; None when it is inside the dead band or larger than a jump): the parts the depth
        did not place this frame (hidden, resting) should be moved by it
        (:func:`tracker.filter.camera_motion.follow_correction`), or they keep the dense odometry's drift while a
        hand is in view (3.9 mm in 25 frames on a tuning seed while the corrected pose stayed within 0.15 mm). The
        state then refers to the corrected pose; a correction inside the dead band is left for later frames."""
        if self.fused is None or not self._observe_pending:
            return None
        self._observe_pending = False
        step = self.fused.correct(dict(landmarks), dict(corners), self._plane)
        self.pose = step.pose
        if self._applied is None:
            return None
        Q = step.pose.as_matrix()
        M = invert(Q) @ self._applied
        dt, dr = motion_size(M)
        if dt <= DEADBAND_M and np.degrees(dr) <= DEADBAND_DEG:
            return None
        self._applied = Q
        if dt > MAX_STEP_M or np.degrees(dr) > MAX_STEP_DEG:
            return None  # an override of the dense odometry by the parts: not a motion to give the hidden parts
        return M

    def _restart(self, T_wc: np.ndarray, table) -> None:
        """Take the tracker's camera frame for the camera at ``T_wc`` (no motion applied) and anchor the camera-frame
        ``table`` (if any) at this pose, so that the plane stays where it was in the camera frame."""
        self._applied = T_wc
        self._history.clear()
        if table is not None and self._table_world is not None:
            self.anchor_table(table)

    def _remember(self, now: float, poses: Mapping[str, Pose], motion: np.ndarray | None) -> None:
        """World-frame part positions for the moving test (the poses are of the previous camera frame, which the
        tracker's state refers to: ``T_applied`` before this step's motion)."""
        ref = self._applied if motion is None else self._applied @ motion
        if ref is None:
            self._history.clear()
            return
        R, t = ref[:3, :3], ref[:3, 3]
        self._history.append((now, {n: R @ p.t + t for n, p in poses.items()}))
        while self._history and now - self._history[0][0] > MOVING_WINDOW_S:
            self._history.popleft()

    # ------------------------------------------------------------------------------------------- table plane
    @property
    def has_table(self) -> bool:
        """A table plane is anchored in the world frame."""
        return self._table_world is not None

    def anchor_table(self, table) -> None:
        """Store ``table`` (a :class:`~tracker.perception.table_plane.TablePlane` in the current camera frame) in
        the world frame; later frames get it from :meth:`table_in_camera`."""
        if table is None:
            self._table_world = None
            return
        R, t = self.pose.R, self.pose.t
        n_w = R @ np.asarray(table.normal, np.float64)
        d_w = float(table.offset) - float(n_w @ t)
        self._table_world = (n_w, d_w, table)

    def table_in_camera(self):
        """The anchored table plane in the current camera frame (None when none is anchored); with ``fused``, the
        plane measured in the current frame where there is one. Meant for frames that applied a camera motion
        (``moved``); on the others the caller's plane is still the right one."""
        if self._table_world is None:
            return None
        n_w, d_w, plane = self._table_world
        if self._plane is not None:  # fused: the plane measured in this frame (tilt and height exact)
            return dataclasses.replace(plane, normal=np.asarray(self._plane[0], np.float64),
                                       offset=float(self._plane[1]))
        R, t = self.pose.R, self.pose.t
        n_c = R.T @ n_w
        return dataclasses.replace(plane, normal=n_c, offset=d_w + float(n_w @ t))


def _full_size(small: np.ndarray, h: int, w: int) -> np.ndarray:
    """A half-resolution bool mask enlarged to ``h``×``w`` (nearest; a last odd row or column stays False)."""
    if 2 * small.shape[0] > h or 2 * small.shape[1] > w:
        raise ValueError(f"mask {small.shape} is more than half of {h}x{w}")
    return enlarge_twice(np.ascontiguousarray(small, bool), h, w)


def _median_change(a: np.ndarray, b: np.ndarray, min_samples: int = 200) -> float | None:
    """Median absolute difference (metres) of two depth grids over the samples valid in both (None when fewer than
    ``min_samples`` are)."""
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(a) & np.isfinite(b) & (a > 0) & (b > 0)
    if int(ok.sum()) < min_samples:
        return None
    return float(np.median(np.abs(a[ok] - b[ok])))
