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
last detection the plane is detected again; the number of re-detections is reported on stderr.

Writes one JSON line per frame to ``--out`` (default: stdout is left for the report)::

    {"index": i, "poses": {"<name>": {"t": [x, y, z], "q": [x, y, z, w]}}}

(camera frame, metres, Hamilton quaternions). When the recording has ground truth it prints per part the
translation error (mm) and symmetry-aware rotation error (degrees) mean / median / 95th percentile, and the
frame rate achieved. Frames without valid depth near the parts keep the prediction; their number is reported.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


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


def _find_table(frame, intrinsics):
    from tracker.perception.table_plane import TableNotFoundError, detect_table

    if frame.depth is None:
        return None
    try:
        return detect_table(frame.depth, intrinsics)
    except TableNotFoundError:
        return None


TABLE_SHARE_TOLERANCE = 0.005
"""Metres: a grid pixel within this distance of the table plane counts as on it."""
TABLE_SHARE_KEEP = 0.7
"""Re-detect the plane when the on-plane share falls below this fraction of the share at the last detection."""
TABLE_RETRY_FRAMES = 10
"""After a failed re-detection, keep the old plane for this many frames before trying again."""


class _TableFollower:
    """The table plane of a recording whose camera may move (see the module docstring)."""

    def __init__(self, intrinsics, table=None) -> None:
        self.intrinsics = intrinsics
        self.table = table
        self.share = None
        self.redetections = 0
        self.failures = 0
        self._tries = 0
        self._wait = 0

    def update(self, frame):
        """The plane to use for ``frame`` (``None`` while none was found)."""
        from tracker.perception.table_plane import plane_share

        depth = frame.depth
        if depth is None:
            return self.table
        if self.table is None:
            if self._tries < 5:
                self._tries += 1
                self.table = _find_table(frame, self.intrinsics)
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
        new = _find_table(frame, self.intrinsics)
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


def run(args: argparse.Namespace) -> int:
    from tracker.evaluation.pose_errors import PoseErrorLog, format_summary
    from tracker.filter.particle_filter import MultiObjectTracker
    from tracker.sources.recording import RecordingSource, parse_objects

    cfg = _load_config(args)
    src = RecordingSource(args.recording)
    parts, poses = src.parts, src.initial_poses
    if args.objects:
        path = Path(args.objects)
        if not path.is_file():
            raise FileNotFoundError(f"objects file not found: {path}")
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: not valid JSON: {exc}") from exc
        parts, poses = parse_objects(data, path.parent, where=str(path))
    if not parts:
        raise ValueError(f"{args.recording}: no objects to track (objects.json missing or empty; use --objects)")
    missing = [p.name for p in parts if p.name not in poses]
    if args.init == "given" and missing:
        raise ValueError(f"no first-frame pose for part(s) {missing} (give 'pose' in objects.json or use --init auto)")
    first_table = None
    if args.init == "auto" or missing:
        auto = [p for p in parts if args.init == "auto" or p.name in missing]
        try:
            poses, first_table = _auto_poses(src, parts, auto, dict(poses), not args.no_color)
        except BaseException:
            src.close()
            raise
    tracker = MultiObjectTracker(parts, src.intrinsics, cfg, seed=args.seed)
    tracker.initialize(poses)
    detector = None
    colored = [p for p in parts if p.color is not None]
    if colored and not args.no_color:
        from tracker.perception.color_detection import ColorDetector

        detector = ColorDetector.from_parts(colored)
    errors = PoseErrorLog(parts) if src.has_groundtruth else None
    out = open(args.out, "w") if args.out else None  # noqa: SIM115
    follower = _TableFollower(src.intrinsics, first_table)
    table = first_table
    n = skipped = 0
    t_track = 0.0
    t_start = time.perf_counter()
    try:
        for frame in src:
            if args.frames is not None and n >= args.frames:
                break
            table = follower.update(frame)
            dets = detector.detect(frame.color) if detector is not None else None
            t0 = time.perf_counter()
            state = tracker.step(frame, dets, table)
            t_track += time.perf_counter() - t0
            skipped += not state.depth_used
            if out is not None:
                out.write(json.dumps({"index": frame.index, "poses": {k: v.to_dict() for k, v in state.poses.items()}})
                          + "\n")
            if errors is not None:
                gt = src.groundtruth(frame.index)
                if gt:
                    errors.add(state.poses, gt)
            n += 1
    finally:
        if out is not None:
            out.close()
        src.close()
    wall = time.perf_counter() - t_start
    if n == 0:
        raise RuntimeError(f"{args.recording}: the recording has no frames")
    print(f"tracked {n} frames of {len(parts)} part(s) with N = {cfg.n_particles} particles; "
          f"table plane: {'found' if table is not None else 'not found (no table penalty)'}; "
          f"colour: {'on' if detector is not None else 'off (depth only)'}")
    print(f"tracker: {n / max(t_track, 1e-9):.1f} fps ({1000 * t_track / n:.1f} ms/frame); "
          f"overall with decoding and perception: {n / max(wall, 1e-9):.1f} fps")
    if table is not None:
        print(f"table plane re-detected {follower.redetections} time(s) (camera or table moved)"
              + (f"; {follower.failures} re-detection(s) failed, the previous plane was kept" if follower.failures
                 else ""), file=sys.stderr)  # fmt: skip
    if skipped:
        print(f"warning: {skipped} frame(s) had no valid depth near the parts; the prediction was kept",
              file=sys.stderr)
    if errors is not None:
        summary = errors.summary()
        if summary:
            print(format_summary(summary))
    if args.out:
        print(f"poses written to {args.out}")
    return 0
