"""Hands in the loop: the hand tracker run beside the cube tracker (hand-tracking spec §14.1, §14.5–14.7).

:class:`HandLoop` is what the pipeline (and the evaluation runner) call once per frame:

1. :meth:`HandLoop.perceive` (before the cube tracker's step): the colour mask B^c leaves out the pixels that cannot
   be a hand whatever their colour (:meth:`HandLoop.exclusion`): those within ``table_clearance_m`` of the table
   plane (product addition: a wooden table has the chrominance of skin, and a hand is above the table) and those
   inside a part's silhouette whose measured depth is not in front of the part's rendered surface by more than
   δ_z = ``part_clearance_m`` (spec §14.1: the part's own surface; the parts are taken at their last estimated poses).
   Then one :class:`~tracker.hands.tracker.HandTracker` step and the hand masks M^h_k.
2. :meth:`HandLoop.occluder_mask` (spec §14.5): H_k = the union of the hand masks and of the colour components
   that reach into a hand's box (a bare forearm), dilated by r_occ = 5 px, full resolution, for the cube tracker's
   occluder prior (``MultiObjectTracker.step(..., occluders=H_k)``).
3. :meth:`HandLoop.update_contacts` (after the cube tracker's step, spec §14.6): each part's silhouette S_j and its
   rendered depth at the new estimated pose, computed by a ray–box test only in a window around the hand boxes, go
   to the :class:`~tracker.hands.contact.ContactMonitor` with the hands' and parts' image velocities and the parts'
   positions; the result is touching / holding per (hand, part).
4. :meth:`HandLoop.touched_parts` feeds the connection gate of §14.7 (``Mode.set_hand_contacts``); None while no hand
   is tracked (gate open, seed behaviour).

Overlap with the cube tracker (product addition, ``HandLoopConfig.overlap``): :meth:`HandLoop.start` runs step 1 and
the occluder mask of step 2 (:meth:`HandLoop.step`) in a worker and :meth:`HandLoop.wait` joins it. The worker
(``HandLoopConfig.worker``) is a child process by default (:mod:`tracker.hands.process`: frames through shared
memory, the same results; a child that dies is reported and restarted): in the server the step's Python parts in a
thread competed with the pipeline thread for the interpreter lock, and the step took twice its CPU time; "thread"
runs it in a thread of this process (OpenCV, numpy and the hand kernels release the lock for most of the step).
With ``"lagged"`` (default) the cube tracker of frame k does not wait for the hands of frame k: its occluder
prior is H_{k−1} predicted to frame k (:meth:`HandLoop.predicted_occluder_mask`: each 8-connected piece of the
undilated H_{k−1} moved by the mean image velocity of the hands whose boxes it reaches into, then dilated by r_occ),
made by the worker at the end of step k−1; with ``"wait"`` it waits for H_k (the hand step then overlaps only the
colour detection); ``"off"`` runs everything in the caller's thread.

Parts without a box shape (``PartSpec.box`` None) have no silhouette here: they are neither excluded nor touched.
Units: pixels of the colour image (end-exclusive boxes), metres, camera frame.
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numba as nb
import numpy as np

from tracker.geometry.camera import Intrinsics
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose
from tracker.hands import order_stats
from tracker.hands.contact import R_TOUCH, ContactMonitor
from tracker.hands.process import HandProcess, HandProcessError, hand_masks_from, mask_from, park, take_parked
from tracker.hands.tracker import HandEstimate, HandTracker, HandTrackerConfig
from tracker.os_names import name_os_thread

OVERLAP_MODES = ("lagged", "wait", "off")
WORKERS = ("process", "thread")


@dataclass(frozen=True)
class HandLoopConfig:
    """``tracker``: the hand tracker's configuration; ``occluder_prior``: give the cube tracker the hand mask as its
    occluder prior (spec §14.5; switchable); ``table_clearance_m``: pixels closer than this to the table plane are
    not hand; ``part_clearance_m``: δ_z of the part-surface exclusion (spec §14.1); ``occluder_radius_px``: r_occ
    (spec §14.5); ``occluder_arm``: add the forearm (the colour components reaching into a hand's box) to H_k;
    ``overlap``: "lagged" | "wait" | "off", how the pipeline runs the hand step beside the cube tracker (module
    docstring); ``worker``: "process" | "thread", where :meth:`HandLoop.start` runs the step unless ``overlap`` is
    "off" (a child process, :mod:`tracker.hands.process`, or a thread of this process); ``step_timeout_s``: seconds
    the process worker may take for one step before it counts as hung and is restarted (its first step also loads the
    compiled kernels and fits the session background, which on a machine loaded far beyond its cores took longer than
    the default). The prior is off by default:
    on guidance-demo tuning seeds 0–2 (300 frames, tracked poses) the cube tracker had 46 part-frames > 10 mm off
    without it, 68 with H_k and 80 with the lagged H_{k−1}; without it the tracker never waits for the hand step."""

    tracker: HandTrackerConfig = field(default_factory=HandTrackerConfig)
    occluder_prior: bool = False
    table_clearance_m: float = 0.015
    part_clearance_m: float = 0.01
    occluder_radius_px: int = 5
    occluder_arm: bool = True
    overlap: str = "lagged"
    worker: str = "process"
    step_timeout_s: float = 20.0

    def __post_init__(self) -> None:
        if self.overlap not in OVERLAP_MODES:
            raise ValueError(f"hand loop overlap must be one of {', '.join(OVERLAP_MODES)}, got {self.overlap!r}")
        if self.worker not in WORKERS:
            raise ValueError(f"hand loop worker must be one of {', '.join(WORKERS)}, got {self.worker!r}")


@nb.njit(cache=True, nogil=True)
def _slab_grid(R, o, half, x, y, out):
    """Slab test of the rays (x[j], y[i], 1) (camera frame) against the box of half extents ``half`` whose frame has
    rotation ``R`` (box → camera) and sees the camera centre at ``o``; writes the entry depth or inf into ``out``."""
    for i in range(y.shape[0]):
        for j in range(x.shape[0]):
            t_near = -np.inf
            t_far = np.inf
            for a in range(3):
                d = R[0, a] * x[j] + R[1, a] * y[i] + R[2, a]
                if d == 0.0:
                    if abs(o[a]) > half[a]:
                        t_far = -1.0
                        break
                    continue
                t1 = (-half[a] - o[a]) / d
                t2 = (half[a] - o[a]) / d
                t_near = max(t_near, min(t1, t2))
                t_far = min(t_far, max(t1, t2))
            if t_near <= t_far and t_far > 0.0 and t_near > -np.inf:
                out[i, j] = max(t_near, 0.0)
            else:
                out[i, j] = np.inf


@nb.njit(cache=True, nogil=True)
def _near_plane(z, rx, ry, n, off, clearance, out):
    """Mark the pixels of the depth grid ``z`` (rays (rx[j], ry[i], 1)) within ``clearance`` of the plane
    n·X + off = 0 (a NaN depth is not: its comparison is false). Branch-free, so that the inner loop vectorises."""
    for i in range(z.shape[0]):
        b = n[1] * ry[i]
        for j in range(z.shape[1]):
            out[i, j] |= abs(z[i, j] * (n[0] * rx[j] + b + n[2]) + off) < clearance


@nb.njit(cache=True, nogil=True)
def _window(pts, fx, fy, cx, cy, W, H):
    """(ok, u0, v0, u1, v1) of :meth:`HandLoop._part_window` from the camera-frame vertices ``pts`` [K, 3]: the
    projected vertices' box, floor − 1 / ceil + 2, clipped to W×H; ok False if a vertex is within 1 mm of the camera
    plane or the box is empty."""
    zmin = np.inf
    for k in range(pts.shape[0]):
        zmin = min(zmin, pts[k, 2])
    if zmin <= 1e-3:
        return False, 0, 0, 0, 0
    umin = vmin = np.inf
    umax = vmax = -np.inf
    for k in range(pts.shape[0]):
        u = fx * pts[k, 0] / pts[k, 2] + cx
        v = fy * pts[k, 1] / pts[k, 2] + cy
        umin = min(umin, u)
        umax = max(umax, u)
        vmin = min(vmin, v)
        vmax = max(vmax, v)
    u0 = max(int(np.floor(umin)) - 1, 0)
    v0 = max(int(np.floor(vmin)) - 1, 0)
    u1 = min(int(np.ceil(umax)) + 2, W)
    v1 = min(int(np.ceil(vmax)) + 2, H)
    return u1 > u0 and v1 > v0, u0, v0, u1, v1


def _box_rays(part: PartSpec, pose: Pose, intrinsics: Intrinsics, u: np.ndarray, v: np.ndarray) -> tuple:
    """(half extents, R, camera centre in the box frame, ray x [len(u)], ray y [len(v)]) for :func:`_slab_grid`."""
    half = np.asarray(part.box, np.float64) / 2.0
    R = np.ascontiguousarray(pose.R, np.float64)
    o = -R.T @ np.asarray(pose.t, np.float64)  # camera centre in the box frame
    x = (np.asarray(u, np.float64) - intrinsics.cx) / intrinsics.fx
    y = (np.asarray(v, np.float64) - intrinsics.cy) / intrinsics.fy
    return half, R, o, x, y


def box_part_depth(part: PartSpec, pose: Pose, intrinsics: Intrinsics, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Depth (camera z, metres; ``inf`` where the ray misses) of box part ``part`` at ``pose`` seen through the pixel
    grid ``u`` (columns, 1-D) × ``v`` (rows, 1-D): a [len(v), len(u)] float32 array (slab test per pixel)."""
    half, R, o, x, y = _box_rays(part, pose, intrinsics, u, v)
    out = np.empty((len(y), len(x)), np.float32)
    _slab_grid(R, o, half, x, y, out)
    return out


@nb.njit(cache=True, nogil=True)
def _mark_part_surface(R, o, half, x, y, z, u0, v0, clearance, out):
    """The part-surface exclusion of one part in one pass: ``out[v0 + i, u0 + j] |= `` the ray (x[j], y[i], 1) hits
    the box (:func:`_slab_grid`, its depth rounded to float32 as there) and the measured depth ``z[v0 + i, u0 + j]``
    is not in front of it by more than ``clearance`` (float32), i.e. ``isfinite(zr) & (z >= zr − clearance)`` with
    numpy's float32 arithmetic."""
    row = np.empty((1, x.shape[0]), np.float32)
    for i in range(y.shape[0]):
        _slab_grid(R, o, half, x, y[i : i + 1], row)
        for j in range(x.shape[0]):
            zr = row[0, j]
            if zr != np.inf and z[v0 + i, u0 + j] >= zr - clearance:
                out[v0 + i, u0 + j] = True


@nb.njit(cache=True, nogil=True)
def _mark_part(pts, R, o, half, fx, fy, cx, cy, W, H, s, z, clearance, out):
    """The part-surface exclusion of one part at the working resolution (every ``s``-th full-resolution pixel), all in
    one call: its window (:func:`_window` of its camera-frame vertices ``pts``, full-resolution px, then the first
    working pixel at or after each bound), the rays of the window's working pixels ((u·s − cx) / fx, (v·s − cy) / fy,
    float64 as :func:`_box_rays` makes them) and :func:`_mark_part_surface` on the working depth ``z``. The same
    operations as :meth:`HandLoop.exclusion` made them per part in Python (bit-identical marks), except that the window
    now ends at the working image's last column and row: where the scale does not divide the image size (not the
    default 2 on 640×480) a window reaching the image's right or bottom edge went one working pixel past them, and the
    marking wrote into the next row's first pixel."""
    ok, u0, v0, u1, v1 = _window(pts, fx, fy, cx, cy, W, H)
    if not ok:
        return
    u0, v0 = -(-u0 // s), -(-v0 // s)
    u1, v1 = min(-(-u1 // s), z.shape[1]), min(-(-v1 // s), z.shape[0])
    if u1 <= u0 or v1 <= v0:
        return
    x = np.empty(u1 - u0)
    for j in range(u1 - u0):
        x[j] = (np.float64((u0 + j) * s) - cx) / fx
    y = np.empty(v1 - v0)
    for i in range(v1 - v0):
        y[i] = (np.float64((v0 + i) * s) - cy) / fy
    _mark_part_surface(R, o, half, x, y, z, u0, v0, clearance, out)


class HandLoop:
    """The hand tracker, the exclusion of table and part pixels, the occluder mask and touching / holding (see the
    module docstring). ``parts``: the parts of the scene; ``intrinsics``: of the colour (and registered depth) image."""

    def __init__(self, parts: list[PartSpec], intrinsics: Intrinsics, config: HandLoopConfig | None = None) -> None:
        self.config = config or HandLoopConfig()
        self._all_parts = list(parts)
        self.parts = {p.name: p for p in parts if p.box is not None}
        self.intrinsics = intrinsics
        self.tracker = HandTracker(self.config.tracker, focal=intrinsics.fx)
        self.contacts = ContactMonitor()
        self.estimates: list[HandEstimate] = []
        self._masks: dict[int, np.ndarray] | None = {}  # None: not made yet from the tracker (see masks)
        self.states: dict[tuple[int, str], str] = {}
        self._centres: dict[str, np.ndarray] = {}  # projected part centres of the previous frame (px)
        self.positions: dict[int, np.ndarray] = {}  # per hand: camera-frame point of its box centre (m)
        self._rays: tuple[tuple[int, int], np.ndarray, np.ndarray] | None = None
        self._vertices = {n: p.vertices() for n, p in self.parts.items()}
        self._halves = {n: np.asarray(p.box, np.float64) / 2.0 for n, p in self.parts.items()}  # box half extents
        self.occluder: np.ndarray | None = None  # H_k of the last step (HandLoop.step)
        self.next_occluder: np.ndarray | None = None  # H_k predicted to frame k + 1 ("lagged")
        self.step_seconds = (0.0, 0.0)  # wall, thread CPU of the last step
        self._pool: ThreadPoolExecutor | None = None
        self._pending: Future | None = None
        self._process: HandProcess | None = None
        self._process_pending = False

    # ------------------------------------------------------------------ the step in a worker thread
    def step(self, color: np.ndarray, depth: np.ndarray | None, table_plane: tuple[np.ndarray, float] | None,
             poses: dict[str, Pose]) -> None:  # fmt: skip
        """:meth:`perceive`, then (occluder prior on) H_k into :attr:`occluder` and, with ``overlap`` "lagged", its
        prediction to the next frame into :attr:`next_occluder`; :attr:`step_seconds` its wall and thread CPU time."""
        t0, c0 = time.perf_counter(), time.thread_time()
        self.perceive(color, depth, table_plane, poses)
        self.occluder = self.next_occluder = None
        if self.config.occluder_prior:
            union = self._occluder_union()
            if union is not None:
                self.occluder = self.occluder_mask(union)
                if self.config.overlap == "lagged":
                    self.next_occluder = self.predicted_occluder_mask(union)
        self.step_seconds = (time.perf_counter() - t0, time.thread_time() - c0)

    def start(self, color: np.ndarray, depth: np.ndarray | None, table_plane: tuple[np.ndarray, float] | None,
              poses: dict[str, Pose]) -> None:  # fmt: skip
        """:meth:`step` in the loop's worker (in the caller's thread with ``overlap`` "off"); with ``worker`` "thread"
        the arrays must not change until :meth:`wait` returns (``poses`` is copied; the process worker copies the
        frame). Until then only :attr:`next_occluder` of the previous step and :meth:`touched_parts` may be read.

        With ``worker`` "process" the step's results (:attr:`estimates`, :attr:`masks`, :attr:`occluder`,
        :attr:`next_occluder`, :attr:`step_seconds`) are the child's, taken by :meth:`wait`; :attr:`tracker` is not
        advanced. A frame the step cannot take, or a hand process that died (it is restarted), raises from
        :meth:`wait`, as an error of the step in the thread does."""
        self.wait()
        if self.config.overlap == "off":
            self.step(color, depth, table_plane, poses)
            return
        if self.config.worker == "process":
            if self._process is None:  # a parked child of an earlier loop of these parts, or a new one
                self._process = take_parked(self._all_parts, self.intrinsics, self.config) or HandProcess(
                    self._all_parts, self.intrinsics, self.config, step_timeout=self.config.step_timeout_s)
            self._process.submit(color, depth, table_plane, poses)
            self._process_pending = True
            return
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="hands",
                                            initializer=name_os_thread)
        self._pending = self._pool.submit(self.step, color, depth, table_plane, dict(poses))

    def stage(self, color: np.ndarray, depth: np.ndarray | None) -> bool:
        """Hand a frame to the hand process ahead of its :meth:`start` (:meth:`HandProcess.stage`: the copy into the
        shared memory leaves the caller of :meth:`start`); may be called from another thread. Whether it was staged
        (only with the process worker once its process runs; the arrays must not change until :meth:`start`)."""
        proc = self._process
        if proc is None or self.config.overlap == "off":
            return False
        return proc.stage(color, depth)

    def wait(self) -> None:
        """Join the step started by :meth:`start` (re-raises its exception); returns at once if none is pending."""
        pending, self._pending = self._pending, None
        if pending is not None:
            pending.result()
        if self._process_pending:
            self._process_pending = False
            assert self._process is not None
            try:
                res = self._process.result()
            except HandProcessError:
                self.estimates, self._masks = [], {}  # the process died: its hands are unknown
                self.occluder = self.next_occluder = None
                raise
            if res is not None:
                self._take(res)

    def _take(self, res: dict) -> None:
        """A step result of the hand process (:func:`tracker.hands.process.step_result`) as this loop's state."""
        size, scale = res["size"], res["scale"]
        self.estimates = res["estimates"]
        self._masks = hand_masks_from(res["masks"], size, scale)
        self.occluder = mask_from(res["occluder"], size)
        self.next_occluder = mask_from(res["next_occluder"], size)
        self.step_seconds = res["seconds"]

    @property
    def masks(self) -> dict[int, np.ndarray]:
        """The hand masks M_k of the last step: full-resolution bool H×W per track id
        (:meth:`HandTracker.hand_masks`)."""
        if self._masks is None:
            self._masks = self.tracker.hand_masks()
        return self._masks

    @property
    def worker_pid(self) -> int | None:
        """Process id of the hand process (``worker`` "process" after the first :meth:`start`), else None."""
        return None if self._process is None else self._process.pid

    def close(self, keep_process: bool = False) -> None:
        """Join a pending step (its error is dropped) and end the worker thread or process; with ``keep_process`` a
        healthy hand process is kept for the next loop of the same parts instead (:func:`tracker.hands.process.park`:
        the server's next pipeline after its source loops then needs no new process)."""
        try:
            self.wait()
        except Exception:  # noqa: BLE001 - closing: the step's error was or will not be reported
            pass
        if self._pool is not None:
            self._pool.shutdown(wait=False)
            self._pool = None
        if self._process is not None:
            if keep_process:
                park(self._process)
            else:
                self._process.close()
            self._process = None

    def tracker_occluders(self) -> np.ndarray | None:
        """The occluder prior for this frame's cube-tracker step: H_{k−1} predicted to frame k with ``overlap``
        "lagged" (readable while the step runs), else H_k (after :meth:`wait`); None with the prior off."""
        if not self.config.occluder_prior:
            return None
        return self.next_occluder if self.config.overlap == "lagged" else self.occluder

    # ------------------------------------------------------------------ per frame
    def perceive(self, color: np.ndarray, depth: np.ndarray | None, table_plane: tuple[np.ndarray, float] | None,
                 poses: dict[str, Pose]) -> list[HandEstimate]:  # fmt: skip
        """One hand-tracker step on the frame (RGB uint8 H×W×3, depth metres or None); ``table_plane`` ``(unit
        normal, offset)`` or None; ``poses``: the parts' last estimated poses (camera frame)."""
        exclude = self.exclusion(depth, table_plane, poses)
        self.estimates = self.tracker.process(color, depth, exclude)
        self._masks = None  # made from the tracker when first read (the hand process never needs them full-size)
        return self.estimates

    def exclusion(self, depth: np.ndarray | None, table_plane: tuple[np.ndarray, float] | None,
                  poses: dict[str, Pose]) -> np.ndarray | None:  # fmt: skip
        """Working-resolution bool mask of the pixels that cannot be a hand (table plane, part surfaces), sampled at
        the full-resolution pixels (s·i, s·j), s = the tracker's scale; None without depth."""
        if depth is None:
            return None
        s = self.tracker.s
        H, W = depth.shape
        z = np.ascontiguousarray(depth[::s, ::s][: H // s, : W // s])  # the kernels' loops vectorise on a copy
        out = np.zeros(z.shape, bool)
        cfg = self.config
        intr = self.intrinsics
        with np.errstate(invalid="ignore"):
            if table_plane is not None:
                n, off = table_plane
                if self._rays is None or self._rays[0] != z.shape:
                    self._rays = (z.shape, (np.arange(z.shape[1]) * s - intr.cx) / intr.fx,
                                  (np.arange(z.shape[0]) * s - intr.cy) / intr.fy)  # fmt: skip
                _, rx, ry = self._rays
                _near_plane(z, rx, ry, np.asarray(n, np.float64), float(off), cfg.table_clearance_m, out)
            clearance = np.float32(cfg.part_clearance_m)
            for name, half in self._halves.items():
                pose = poses.get(name)
                if pose is None:
                    continue
                # the vertices and the camera centre in the box frame as _part_window and _box_rays compute them
                R = np.ascontiguousarray(pose.R, np.float64)
                pts = self._vertices[name] @ np.asarray(pose.R).T + np.asarray(pose.t)
                o = -R.T @ np.asarray(pose.t, np.float64)
                _mark_part(pts, R, o, half, float(intr.fx), float(intr.fy), float(intr.cx), float(intr.cy), W, H, s,
                           z, clearance, out)  # fmt: skip
        return out

    def _part_window(self, part: PartSpec, pose: Pose | None, H: int, W: int) -> tuple[int, int, int, int] | None:
        """End-exclusive pixel box [u0, v0, u1, v1] of the part's projected vertices (+1 px), clipped; None if none."""
        if pose is None:
            return None
        pts = self._vertices[part.name] @ np.asarray(pose.R).T + np.asarray(pose.t)
        intr = self.intrinsics
        ok, u0, v0, u1, v1 = _window(pts, float(intr.fx), float(intr.fy), float(intr.cx), float(intr.cy), W, H)
        return (u0, v0, u1, v1) if ok else None

    def occluder_mask(self, union: np.ndarray | None = None) -> np.ndarray | None:
        """H_k (spec §14.5): full-resolution bool H×W, the dilation by r_occ of the union of the hand masks and of
        the colour components that reach into a hand's box (a bare forearm; :meth:`HandTracker.arm_mask`); None
        without hands. ``union``: the undilated H_k at the working resolution (:meth:`_occluder_union`) if made."""
        union = self._occluder_union() if union is None else union
        if union is None:
            return None
        s = self.tracker.s
        x, y, w, h = cv2.boundingRect(union)
        crop = union[y : y + h, x : x + w]
        if s > 1:
            crop = cv2.resize(crop, (w * s, h * s), interpolation=cv2.INTER_NEAREST)
        return self._dilated([(x * s, y * s, crop)])

    def predicted_occluder_mask(self, union: np.ndarray | None = None) -> np.ndarray | None:
        """H_k predicted to frame k + 1 (``overlap`` "lagged"): every 8-connected piece of the undilated union of
        :meth:`occluder_mask` moved by the mean image velocity (full px per frame, rounded) of the hands whose boxes
        it reaches into (of all hands if it reaches none), then dilated by r_occ; None without hands. ``union``: the
        undilated H_k at the working resolution (:meth:`_occluder_union`) if already made."""
        union = self._occluder_union() if union is None else union
        if union is None:
            return None
        s = self.tracker.s
        x, y, w, h = cv2.boundingRect(union)
        n, lab, stats, _ = cv2.connectedComponentsWithStats(union[y : y + h, x : x + w], connectivity=8,
                                                            ltype=cv2.CV_32S)  # fmt: skip
        hands = [(e.box, e.state[4:6]) for e in self.estimates if e.box[2] > e.box[0] and e.box[3] > e.box[1]]
        pieces = []
        for i in range(1, n):
            bx, by, bw, bh = (int(v) for v in stats[i, :4])
            piece = (lab[by : by + bh, bx : bx + bw] == i).astype(np.uint8)
            if s > 1:
                piece = cv2.resize(piece, (bw * s, bh * s), interpolation=cv2.INTER_NEAREST)
            px, py = (bx + x) * s, (by + y) * s  # the piece's top-left full-resolution pixel

            def reaches(b, px=px, py=py, piece=piece) -> bool:
                return piece[max(b[1] - py, 0) : max(b[3] - py, 0), max(b[0] - px, 0) : max(b[2] - px, 0)].any()

            vel = [v for b, v in hands if reaches(b)] or [v for _, v in hands]
            du, dv = (int(round(float(c))) for c in np.mean(vel, axis=0)) if vel else (0, 0)
            pieces.append((px + du, py + dv, piece))
        return self._dilated(pieces)

    def _occluder_union(self) -> np.ndarray | None:
        """The undilated H_k at the working resolution: uint8 0/1 union of the hand masks and the arm mask; None
        without hands or if empty."""
        small = self.tracker.hand_masks_small()
        if not any(e.id in small and e.box[2] > e.box[0] and e.box[3] > e.box[1] for e in self.estimates):
            return None
        union: np.ndarray | None = None
        for m in small.values():
            union = m.copy() if union is None else union | m
        arm = self.tracker.arm_mask_small() if self.config.occluder_arm else None
        if arm is not None:
            union = arm if union is None else union | arm
        if union is None or not union.any():
            return None
        return union

    def _dilated(self, pieces: list[tuple[int, int, np.ndarray]]) -> np.ndarray | None:
        """Full-resolution bool H×W: the uint8 0/1 full-resolution ``pieces`` (x, y, image: the image's top-left pixel
        and content) pasted, clipped to the image, and dilated by a disk of radius r_occ (computed only around them);
        None if no piece lands in the image."""
        assert self.tracker.full_size is not None
        W, H = self.tracker.full_size
        rects = []
        for x, y, img in pieces:
            x0, y0 = max(x, 0), max(y, 0)
            x1, y1 = min(x + img.shape[1], W), min(y + img.shape[0], H)
            if x1 > x0 and y1 > y0:
                rects.append((x0, y0, x1, y1, img[y0 - y : y1 - y, x0 - x : x1 - x]))
        if not rects:
            return None
        r = int(self.config.occluder_radius_px)
        X0, Y0 = max(min(q[0] for q in rects) - r, 0), max(min(q[1] for q in rects) - r, 0)
        X1, Y1 = min(max(q[2] for q in rects) + r, W), min(max(q[3] for q in rects) + r, H)
        canvas = np.zeros((Y1 - Y0, X1 - X0), np.uint8)
        for x0, y0, x1, y1, img in rects:
            canvas[y0 - Y0 : y1 - Y0, x0 - X0 : x1 - X0] |= img
        k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
        out = np.zeros((H, W), bool)
        out[Y0:Y1, X0:X1] = cv2.dilate(canvas, k).astype(bool)
        return out

    def update_contacts(self, poses: dict[str, Pose], depth: np.ndarray | None) -> dict[tuple[int, str], str]:
        """Touching / holding after the cube tracker's step (``poses``: its new estimates): ``{(hand id, part):
        "touching" | "holding"}`` (spec §14.6)."""
        centres: dict[str, np.ndarray] = {}
        for name, pose in poses.items():
            if name in self.parts and pose is not None and pose.t[2] > 1e-3:
                centres[name] = self.intrinsics.project(np.asarray(pose.t, float)[None])[0]
        part_vel = {n: c - self._centres[n] for n, c in centres.items() if n in self._centres}
        self._centres = centres
        hand_vel = {e.id: np.asarray(e.state[4:6], float) for e in self.estimates}
        positions = {n: np.asarray(p.t, float) for n, p in poses.items() if n in self.parts and p is not None}
        masks, sils, part_depths, crop_depth = {}, {}, {}, None
        win = self._hands_window()
        if win is not None:
            u0, v0, u1, v1 = win
            masks = {h: m[v0:v1, u0:u1] for h, m in self.masks.items()}
            crop_depth = None if depth is None else depth[v0:v1, u0:u1]
            us, vs = np.arange(u0, u1), np.arange(v0, v1)
            H, W = self.masks[next(iter(self.masks))].shape
            for name, part in self.parts.items():
                pw = self._part_window(part, poses.get(name), H, W)
                if pw is None or pw[0] >= u1 or pw[2] <= u0 or pw[1] >= v1 or pw[3] <= v0:
                    continue
                # the slab test only inside the part's window: every ray outside it misses the box (inf)
                a0, b0 = max(pw[0], u0) - u0, max(pw[1], v0) - v0
                a1, b1 = min(pw[2], u1) - u0, min(pw[3], v1) - v0
                zr = np.full((len(vs), len(us)), np.inf, np.float32)
                zr[b0:b1, a0:a1] = box_part_depth(part, poses[name], self.intrinsics, us[a0:a1], vs[b0:b1])
                sils[name] = np.isfinite(zr)
                part_depths[name] = zr
        self.states = self.contacts.update(masks, sils, positions, crop_depth, part_depths, hand_vel, part_vel)
        self.positions = self._hand_positions(depth)
        return self.states

    def _hand_positions(self, depth: np.ndarray | None) -> dict[int, np.ndarray]:
        """Camera-frame point (m) of each hand's box centre at the median valid depth of its skin pixels."""
        out: dict[int, np.ndarray] = {}
        if depth is None:
            return out
        for e in self.estimates:
            m = self.masks.get(e.id)
            u0, v0, u1, v1 = e.box
            if m is None or u1 <= u0 or v1 <= v0:
                continue
            z = depth[v0:v1, u0:u1][m[v0:v1, u0:u1]]
            z = z[np.isfinite(z) & (z > 0)]
            if len(z):
                uc, vc = (u0 + u1 - 1) / 2.0, (v0 + v1 - 1) / 2.0
                zc = order_stats.median(z)  # = float(np.median(z)) (the float32 value, widened)
                out[e.id] = self.intrinsics.backproject(np.array([uc]), np.array([vc]), np.array([zc]))[0]
        return out

    def _hands_window(self) -> tuple[int, int, int, int] | None:
        """The hand boxes' bounding rectangle grown by r_touch + 1 px (all contact tests happen inside it)."""
        boxes = [e.box for e in self.estimates if e.box[2] > e.box[0] and e.box[3] > e.box[1]]
        if not boxes or not self.masks:
            return None
        H, W = self.masks[next(iter(self.masks))].shape
        g = R_TOUCH + 1
        u0, v0 = max(min(b[0] for b in boxes) - g, 0), max(min(b[1] for b in boxes) - g, 0)
        u1, v1 = min(max(b[2] for b in boxes) + g, W), min(max(b[3] for b in boxes) + g, H)
        return (u0, v0, u1, v1) if u1 > u0 and v1 > v0 else None

    # ------------------------------------------------------------------ outputs
    def touched_parts(self) -> set[str] | None:
        """Parts a hand touches or holds now, for the connection gate; None while no hand is tracked (gate open)."""
        touched = self.contacts.touched_parts()
        if not self.estimates and not touched:
            return None
        return touched

    def hands(self) -> list[dict]:
        """Per hand: ``{"id", "box": [u0, v0, u1, v1], "score", "velocity": [du, dv] px/frame, "touching": [parts],
        "holding": [parts], "text", "position"}`` with ``text`` e.g. "holding the red cube" (empty when neither) and
        ``position`` the camera-frame point (m) of the box centre at the hand's median depth, or None."""
        out = []
        for e in self.estimates:
            holding = sorted(p for (h, p), st in self.states.items() if h == e.id and st == "holding")
            touching = sorted(p for (h, p), st in self.states.items() if h == e.id and st == "touching")
            out.append({"id": int(e.id), "box": [int(b) for b in e.box], "score": round(float(e.score), 3),
                        "velocity": [round(float(e.state[4]), 2), round(float(e.state[5]), 2)],
                        "touching": touching, "holding": holding, "text": self.describe(holding, touching),
                        "position": None if e.id not in self.positions else
                        [round(float(x), 4) for x in self.positions[e.id]]})  # fmt: skip
        return out

    def describe(self, holding: list[str], touching: list[str]) -> str:
        """"holding the red cube", "touching the blue cube and the green cube" or ""."""
        verb, names = ("holding", holding) if holding else ("touching", touching)
        if not names:
            return ""
        words = [f"the {self._label(n)}" for n in names]
        return f"{verb} " + (words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1])

    def _label(self, name: str) -> str:
        part = self.parts.get(name)
        return f"{name} cube" if part is not None and part.is_cube and " " not in name else name
