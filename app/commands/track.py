"""``assembly-agent track RECORDING``: run the 6-DoF multi-object depth tracker over a recording.

Tracks the parts of the recording's ``objects.json`` (or ``--objects FILE`` in the same format) from their
first-frame poses. ``--init given`` uses the poses of objects.json (an error when one is missing); ``--init auto``
finds every part's pose in the first frame (``initialize_poses``: table plane,
objects above it, colour blob or footprint/height match, ICP); without ``--init`` the given poses are used and
only the missing ones are found automatically. Each automatically initialised part is reported on stderr with its
pose and ICP residual. Colour detection is used for parts with a colour (depth only otherwise), the table plane
when it can be found in the first frames. For a moving camera the plane is re-detected when it no longer fits the
depth: every frame the share of a coarse pixel grid within 5 mm of the plane is measured
(:func:`tracker.perception.table_plane.plane_share`, ~0.2 ms), and when it falls below 70 % of its value right after the
last detection the plane is detected again; the number of re-detections is reported on stderr. A detected plane
is used only when it supports the parts: a plane whose on-plane pixels lie (almost) all within the parts'
bounding spheres at their current estimates is a face of a part (e.g. the floor of a mesh object seen without a
table), not a table, and is ignored (:func:`plane_is_table`); ``--no-table`` disables the plane altogether.
The per-frame work (plane, colour detection, tracker step) is :class:`TrackSession`, which benchmarks reuse so
that they measure exactly what ``track`` does.

Writes one JSON line per frame to ``--out`` (default: stdout is left for the report)::

    {"index": i, "poses": {"<name>": {"t": [x, y, z], "q": [x, y, z, w]}}}

(camera frame, metres, Hamilton quaternions); with the odometry on (``--odometry fused``, the default, or
``default|fastslam``) each line also has
``"camera": {"t", "q", "ok"}``, the camera's pose in the world frame (= the first frame's camera frame; ``ok`` False
when extrapolated). With odometry on, the tracker's particles are moved by the camera's motion before each step
(static parts stay put in the world frame) and the table plane is propagated with the camera instead of re-checked
(re-checked when the odometry fails); see :mod:`tracker.odometry.ego_motion`.

When the recording has ground truth it prints per part the translation error (mm) and symmetry-aware rotation
error (degrees) mean / median / 95th percentile, and the frame rate achieved. Frames without valid depth near
the parts keep the prediction; their number is reported.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

DEFAULT_ODOMETRY = "fused"
"""``--odometry``'s default: :data:`tracker.odometry.ego_motion.DEFAULT_MODE` (kept literal here so that ``--help``
does not import the tracker; a test checks that the two agree)."""


def register(subparsers) -> None:
    p = subparsers.add_parser("track", help="track the parts of a recording with the depth particle filter")
    p.add_argument("recording", help="recording directory (README 'Recording format')")
    p.add_argument("--objects", default=None, help="objects.json to use instead of the recording's own")
    p.add_argument("--out", default=None, help="write per-frame poses as JSON lines to this file")
    p.add_argument("--particles", type=int, default=None, help="number of particles N (default: from the preset)")
    p.add_argument("--config", default=None, help="YAML/TOML file overriding tracker settings")
    p.add_argument("--preset", default=None, help="tracker preset: default, seed-exp1, seed-exp23")
    p.add_argument("--frames", type=int, default=None, help="stop after this many frames")
    p.add_argument("--seed", type=int, default=0, help="random seed of the particle filter")
    p.add_argument("--no-color", action="store_true", help="depth only (ignore part colours)")
    p.add_argument("--no-table", action="store_true",
                   help="do not look for a table plane (e.g. a recording with depth of the object only)")
    p.add_argument("--odometry", default=DEFAULT_ODOMETRY, choices=("default", "fastslam", "fused", "off"),
                   help=f"camera ego-motion (default {DEFAULT_ODOMETRY}; off: a fixed camera's poses are the same): "
                        "the parts are moved by the camera's motion before each step and the table plane is "
                        "propagated; --out still gets camera-frame poses")
    p.add_argument("--hands", action="store_true",
                   help="run the hand tracker beside the part tracker: a hidden part a hand touches is carried by it "
                        "(as the server with --hands); about 7 ms more per frame")
    p.add_argument("--init", default=None, choices=("given", "auto"),
                   help="first-frame poses: 'given' (objects.json) or 'auto' (found in the first frame); "
                        "default: the given ones, missing ones found automatically")
    p.set_defaults(func=run)


def _load_config(args):
    from tracker.filter.tracker_config import TrackerConfig

    if args.config:
        cfg = TrackerConfig.load(args.config, preset=args.preset)
    else:
        cfg = TrackerConfig.preset(args.preset or "default")
    if args.particles is not None:
        if args.particles < 1:
            raise ValueError("--particles must be at least 1")
        cfg = cfg.with_overrides(n_particles=args.particles)
    return cfg


def _find_table(frame, intrinsics, parts=None, poses=None):
    """The table plane of ``frame`` or ``None``; with ``parts``/``poses``, a plane that is not
    :func:`plane_is_table` is rejected too."""
    from tracker.perception.table_plane import TableNotFoundError, detect_table

    if frame.depth is None:
        return None
    try:
        plane = detect_table(frame.depth, intrinsics)
    except TableNotFoundError:
        return None
    if parts and poses and not plane_is_table(frame.depth, intrinsics, plane, parts, poses):
        return None
    return plane


TABLE_SHARE_TOLERANCE = 0.005
"""Metres: a grid pixel within this distance of the table plane counts as on it."""
TABLE_OUTSIDE_MIN = 0.25
"""A plane is a table only when at least this share of its on-plane grid pixels lies outside every part's
bounding sphere (grown by ``TABLE_PART_MARGIN``)."""
TABLE_PART_MARGIN = 0.01
"""Metres added to each part's bounding radius by :func:`plane_is_table`."""


def plane_is_table(depth, intrinsics, plane, parts, poses, step: int = 8) -> bool:
    """Whether ``plane`` is a support under the parts rather than a face of one of them.

    Takes every ``step``-th depth pixel within ``TABLE_SHARE_TOLERANCE`` of the plane (camera frame, metres) and
    counts those farther than ``bounding_radius + TABLE_PART_MARGIN`` from every part's estimated origin; the plane
    is a table when that share is at least ``TABLE_OUTSIDE_MIN``. A recording of an object without a table (depth
    of the object only) has all its on-plane pixels on the object.
    """
    import numpy as np

    z = np.asarray(depth, np.float64)[::step, ::step]
    v, u = np.mgrid[0 : depth.shape[0] : step, 0 : depth.shape[1] : step]
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(z) & (z > 0)
    pts = intrinsics.backproject(u[ok], v[ok], z[ok])
    on = pts[np.abs(pts @ np.asarray(plane.normal, np.float64) + float(plane.offset)) < TABLE_SHARE_TOLERANCE]
    if on.shape[0] == 0:
        return False
    outside = np.ones(on.shape[0], bool)
    for part in parts:
        pose = poses.get(part.name)
        if pose is not None:
            outside &= np.linalg.norm(on - pose.t, axis=1) > part.bounding_radius() + TABLE_PART_MARGIN
    return float(outside.mean()) >= TABLE_OUTSIDE_MIN
TABLE_SHARE_KEEP = 0.7
"""Re-detect the plane when the on-plane share falls below this fraction of the share at the last detection."""
TABLE_RETRY_FRAMES = 10
"""After a failed re-detection, keep the old plane for this many frames before trying again."""


class _TableFollower:
    """The table plane of a recording whose camera may move (see the module docstring)."""

    def __init__(self, intrinsics, table=None, parts=None) -> None:
        self.intrinsics = intrinsics
        self.parts = parts
        self.table = table
        self.share = None
        self.redetections = 0
        self.failures = 0
        self._tries = 0
        self._wait = 0

    def update(self, frame, poses=None):
        """The plane to use for ``frame`` (``None`` while none was found); ``poses``: the parts' latest estimates,
        used to reject planes that are faces of the parts (:func:`plane_is_table`)."""
        from tracker.perception.table_plane import plane_share

        depth = frame.depth
        if depth is None:
            return self.table
        if self.table is None:
            if self._tries < 5:
                self._tries += 1
                self.table = _find_table(frame, self.intrinsics, self.parts, poses)
            if self.table is not None:
                self.share = plane_share(depth, self.intrinsics, self.table, tolerance=TABLE_SHARE_TOLERANCE)
            return self.table
        if self.share is None:
            self.share = plane_share(depth, self.intrinsics, self.table, tolerance=TABLE_SHARE_TOLERANCE)
            return self.table
        if self._wait > 0:
            self._wait -= 1
            return self.table
        share = plane_share(depth, self.intrinsics, self.table, tolerance=TABLE_SHARE_TOLERANCE)
        if share >= TABLE_SHARE_KEEP * self.share:
            return self.table
        new = _find_table(frame, self.intrinsics, self.parts, poses)
        if new is None:
            self.failures += 1
            self._wait = TABLE_RETRY_FRAMES
            return self.table
        self.table = new
        self.share = plane_share(depth, self.intrinsics, new, tolerance=TABLE_SHARE_TOLERANCE)
        self.redetections += 1
        return self.table


def _auto_poses(src, parts, auto, poses, use_color: bool):
    """Find the first-frame poses of the ``auto`` parts; returns (all poses, the table plane used)."""
    from tracker.perception.pose_initialization import initialize_poses

    if len(src) == 0:
        raise RuntimeError(f"{src.root}: the recording has no frames")
    frame = src.read(0)
    if frame.depth is None:
        raise ValueError(f"{src.root}: frame {frame.index} has no depth; cannot initialise "
                         f"{[p.name for p in auto]} automatically (give 'pose' in objects.json)")
    table = _find_table(frame, src.intrinsics)
    if table is None:
        raise ValueError(f"{src.root}: no table plane in frame {frame.index}; cannot initialise "
                         f"{[p.name for p in auto]} automatically (give 'pose' in objects.json)")
    by_name = {p.name: p for p in parts}
    known = {n: (by_name[n], pose) for n, pose in poses.items() if n in by_name and n not in {p.name for p in auto}}
    results = initialize_poses(frame, auto, table=table, use_color=use_color, known=known)
    for name, r in results.items():
        poses[name] = r.pose
        t = ", ".join(f"{v:.4f}" for v in r.pose.t)
        q = ", ".join(f"{v:.4f}" for v in r.pose.q)
        print(f"auto-initialised {name!r} in frame {frame.index}: t = [{t}] m, q = [{q}], residual "
              f"{r.residual_mm:.2f} mm over {r.n_points} points ({r.method})", file=sys.stderr)
    return poses, table


class TrackSession:
    """The per-frame work of ``track``: table plane (followed, see :class:`_TableFollower`), colour detection, one
    tracker step. Benchmarks use it to measure exactly what the command does.

    ``parts``/``poses``: the parts and their first-frame poses (camera frame, metres); ``table``: the first frame's
    plane when already known; ``use_table`` False: never look for one. ``step(frame)`` returns the tracker state and
    the seconds spent in the tracker step (without decoding, plane and colour detection); ``last_cpu`` is the
    thread CPU seconds of that step. ``hands``: run the hand tracker (:class:`tracker.hands.loop.HandLoop`, in this
    thread) after each tracker step, as the pipeline does with hands on: the parts a hand touched in the last frame
    go to the next tracker step (a hidden part a hand touches is carried by it); its thread CPU is ``last_hands_cpu``.
    """

    def __init__(self, parts, intrinsics, poses, cfg, seed: int = 0, use_color: bool = True, table=None,
                 use_table: bool = True, odometry: str = "off", hands: bool = False) -> None:
        from tracker.filter.particle_filter import MultiObjectTracker
        from tracker.odometry.ego_motion import MODES, EgoMotion

        if odometry not in MODES:
            raise ValueError(f"odometry must be one of {', '.join(MODES)}, got {odometry!r}")

        self.parts = list(parts)
        self.config = cfg
        self.tracker = MultiObjectTracker(self.parts, intrinsics, cfg, seed=seed)
        self.tracker.initialize(poses)
        self.poses = dict(poses)
        self.detector = None
        colored = [p for p in self.parts if p.color is not None]
        if colored and use_color:
            from tracker.perception.color_detection import ColorDetector

            self.detector = ColorDetector.from_parts(colored)
        self.follower = _TableFollower(intrinsics, table, self.parts) if use_table else None
        self.table = table if use_table else None
        self.frames = 0
        self.skipped = 0
        self.track_seconds = 0.0
        self.last_cpu = 0.0
        self.carried: list[str] = []
        self.last_ego_cpu = 0.0  # thread CPU seconds of the last odometry stage (mask, odometry, camera motion)
        self.ego = None if odometry == "off" else EgoMotion(odometry, intrinsics, self.parts, seed=seed)
        self.ego_step = None  # the last EgoMotionStep (odometry on)
        self._corners = {n: self.tracker.corners[i] for i, n in enumerate(self.tracker.names)}
        if self.ego is not None and table is not None:
            self.ego.anchor_table(table)
        self.hands = None
        self.last_hands_cpu = 0.0
        if hands:
            from tracker.hands.loop import HandLoop, HandLoopConfig

            self.hands = HandLoop(self.parts, intrinsics, HandLoopConfig(overlap="off"))

    def step(self, frame):
        """Track one frame; returns ``(TrackerState, tracker seconds)``. With odometry on, the camera's motion is
        applied to the tracker first and the table plane is propagated (re-checked when the odometry fails)."""
        if self.ego is not None:
            c0 = time.thread_time()
            self._follow_camera(frame)
            self.last_ego_cpu = time.thread_time() - c0
        elif self.follower is not None:
            self.table = self.follower.update(frame, self.poses)
        dets = None
        if self.detector is not None:
            ahead = frame.meta.get("colour_analysis")  # detected as the frame was decoded (RecordingSource)
            dets = ahead[1] if ahead is not None and ahead[0] == self.detector.detect else \
                self.detector.detect(frame.color)
        fused = self.ego is not None and self.ego.fused is not None
        if fused:
            from tracker.filter.camera_motion import hand_hidden_parts_to_the_odometry

            hand_hidden_parts_to_the_odometry(self.tracker, self.ego)
        touched = self.hands.touched_parts() if self.hands is not None else None
        t0, c0 = time.perf_counter(), time.thread_time()
        state = self.tracker.step(frame, dets, self.table, touched=touched)
        dt = time.perf_counter() - t0
        self.last_cpu = time.thread_time() - c0
        if fused:  # odometry fused: the resting parts check the camera; the hidden parts follow its correction
            from tracker.filter.camera_motion import follow_correction

            c0 = time.thread_time()
            correction = self.ego.observe(self.tracker.landmark_poses, self._corners)
            if correction is not None:
                follow_correction(self.tracker, correction, state.poses)
            self.last_ego_cpu += time.thread_time() - c0
        self.track_seconds += dt
        if self.hands is not None:
            self._track_hands(frame, state.poses)
        self.poses = dict(state.poses)
        self.carried = list(state.carried)
        self.skipped += not state.depth_used
        self.frames += 1
        return state, dt


    def _track_hands(self, frame, poses) -> None:
        """The hand tracker's step on this frame and its touching / holding at the new poses (``hands`` on)."""
        from tracker.filter.frame_context import table_normal_offset

        c0 = time.thread_time()
        self.hands.step(frame.color, frame.depth, table_normal_offset(self.table), poses)
        self.hands.update_contacts(poses, frame.depth)
        self.last_hands_cpu = time.thread_time() - c0

    def _follow_camera(self, frame) -> None:
        """Odometry on: move the tracker's state by the camera's motion; propagate the table when it moved, else
        follow it as with odometry off."""
        from tracker.filter.camera_motion import apply_camera_motion
        from tracker.odometry.ego_motion import frame_hand_boxes

        # hand boxes a source gives (frame.meta) are masked out of the odometry, as in the pipeline
        ego = self.ego.step(frame, self.table, self.poses, self.carried, frame_hand_boxes(frame))
        self.ego_step = ego
        if ego.camera_motion is not None:
            apply_camera_motion(self.tracker, ego.camera_motion)
            self.poses = dict(self.tracker.estimates)
        if self.follower is None:
            return
        if self.ego.moved and self.ego.has_table:  # the camera moved: the plane is propagated
            self.table = self.follower.table = self.ego.table_in_camera()
            return
        # no camera motion applied (failed step, idle, inside the dead band): the plane is followed as with
        # odometry off (a fixed camera sees the same planes with the odometry on as with it off)
        before = self.table
        self.table = self.follower.update(frame, self.poses)
        if self.table is not None and (self.table is not before or not self.ego.has_table):
            self.ego.anchor_table(self.table)


def load_recording_parts(recording, objects=None):
    """``(source, parts, first-frame poses)`` of a recording, with ``objects`` (a path to an objects.json) replacing
    its own parts."""
    from tracker.sources.recording import RecordingSource, parse_objects

    src = RecordingSource(recording)
    parts, poses = src.parts, src.initial_poses
    if objects:
        path = Path(objects)
        if not path.is_file():
            src.close()
            raise FileNotFoundError(f"objects file not found: {path}")
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            src.close()
            raise ValueError(f"{path}: not valid JSON: {exc}") from exc
        parts, poses = parse_objects(data, path.parent, where=str(path))
    if not parts:
        src.close()
        raise ValueError(f"{recording}: no objects to track (objects.json missing or empty; use --objects)")
    return src, parts, dict(poses)


def run(args: argparse.Namespace) -> int:
    from tracker.evaluation.pose_errors import PoseErrorLog, format_summary

    cfg = _load_config(args)
    src, parts, poses = load_recording_parts(args.recording, args.objects)
    missing = [p.name for p in parts if p.name not in poses]
    if args.init == "given" and missing:
        src.close()
        raise ValueError(f"no first-frame pose for part(s) {missing} (give 'pose' in objects.json or use --init auto)")
    first_table = None
    if args.init == "auto" or missing:
        auto = [p for p in parts if args.init == "auto" or p.name in missing]
        try:
            poses, first_table = _auto_poses(src, parts, auto, dict(poses), not args.no_color)
        except BaseException:
            src.close()
            raise
    session = TrackSession(parts, src.intrinsics, poses, cfg, seed=args.seed, use_color=not args.no_color,
                           table=first_table, use_table=not args.no_table, odometry=args.odometry,
                           hands=args.hands)
    if session.detector is not None:  # the colour detection of the next frames beside this one's tracking
        src.analyse_colour(session.detector.detect)
    errors = PoseErrorLog(parts) if src.has_groundtruth else None
    out = open(args.out, "w") if args.out else None  # noqa: SIM115
    n = 0
    t_start = time.perf_counter()
    from tqdm import tqdm

    try:
        total = len(src)
    except TypeError:
        total = None
    if total is not None and args.frames is not None:
        total = min(total, args.frames)
    bar = tqdm(total=total, unit="frame", desc="track", disable=None)
    try:
        for frame in src:
            if args.frames is not None and n >= args.frames:
                break
            state, _ = session.step(frame)
            bar.update(1)
            if out is not None:
                line = {"index": frame.index, "poses": {k: v.to_dict() for k, v in state.poses.items()}}
                if session.ego_step is not None:
                    line["camera"] = {**session.ego_step.pose_world_camera.to_dict(), "ok": session.ego_step.ok}
                out.write(json.dumps(line) + "\n")
            if errors is not None:
                gt = src.groundtruth(frame.index)
                if gt:
                    errors.add(state.poses, gt)
            n += 1
    finally:
        bar.close()
        if out is not None:
            out.close()
        src.close()
    wall = time.perf_counter() - t_start
    if n == 0:
        raise RuntimeError(f"{args.recording}: the recording has no frames")
    t_track, table, follower = session.track_seconds, session.table, session.follower
    if args.no_table:
        table_note = "off (--no-table)"
    else:
        table_note = "found" if table is not None else "not found (no table penalty)"
    print(f"tracked {n} frames of {len(parts)} part(s) with N = {cfg.n_particles} particles; "
          f"table plane: {table_note}; "
          f"colour: {'on' if session.detector is not None else 'off (depth only)'}")
    print(f"tracker: {n / max(t_track, 1e-9):.1f} fps ({1000 * t_track / n:.1f} ms/frame); "
          f"overall with decoding and perception: {n / max(wall, 1e-9):.1f} fps")
    if table is not None and follower is not None:
        print(f"table plane re-detected {follower.redetections} time(s) (camera or table moved)"
              + (f"; {follower.failures} re-detection(s) failed, the previous plane was kept" if follower.failures
                 else ""), file=sys.stderr)  # fmt: skip
    if session.ego is not None:
        print(f"odometry {args.odometry}: {n - session.ego.failures} of {n} camera poses measured, "
              f"{session.ego.failures} extrapolated (the parts kept their camera-frame prediction there)",
              file=sys.stderr)
    if session.skipped:
        print(f"warning: {session.skipped} frame(s) had no valid depth near the parts; the prediction was kept",
              file=sys.stderr)
    if errors is not None:
        summary = errors.summary()
        if summary:
            print(format_summary(summary))
    if args.out:
        print(f"poses written to {args.out}")
    return 0
