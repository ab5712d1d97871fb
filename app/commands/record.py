"""``assembly-agent record --source SOURCE --out DIR [--frames N] [--seconds S]``: record any source to disk.

Writes the recording format of the README ("Recording format"). From the simulator (or another recording)
the per-frame ground truth, the parts with their first-frame poses and the connection events are written too.
"""

from __future__ import annotations

import argparse
import logging

from tracker.sources.base import SourceError
from tracker.sources.recording import RecordingWriter
from tracker.sources.registry import SOURCE_HELP, open_source

log = logging.getLogger(__name__)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "record",
        help="record a source (simulator, camera, recording) to a recording directory",
        description="Record frames from any source into a recording directory (README: 'Recording format'). "
        "Live cameras record until --frames/--seconds or Ctrl-C.",
    )
    p.add_argument("--source", required=True, help=SOURCE_HELP)
    p.add_argument("--out", required=True, help="output recording directory (must not hold a recording yet)")
    p.add_argument("--frames", type=int, default=None, help="stop after N frames")
    p.add_argument("--seconds", type=float, default=None, help="stop after S seconds of source time")
    p.add_argument("--seed", type=int, default=None, help="simulator seed (sim: sources)")
    p.add_argument("--calibration", default=None, help="camera calibration JSON (camera: sources; README 'Sources')")
    p.add_argument("--depth-scale", type=float, default=None,
                   help="metres per stored depth unit (default: the source's, else 0.001)")
    p.add_argument("--color-format", choices=("png", "jpg"), default="png", help="colour image format (png: lossless)")
    p.add_argument("--overwrite", action="store_true", help="replace a recording already in --out")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.frames is not None and args.frames <= 0:
        raise ValueError("--frames must be positive")
    if args.seconds is not None and args.seconds <= 0:
        raise ValueError("--seconds must be positive")
    options = {"seed": args.seed, "calibration": args.calibration}
    if args.frames is not None and args.source.startswith("sim:"):
        options["n_frames"] = args.frames
    src = open_source(args.source, **options)
    try:
        n, t_last, n_gt, n_events = record(src, args)
    finally:
        src.close()
    print(f"wrote {n} frames ({t_last:.2f} s) to {args.out}; ground truth for {n_gt} frames; {n_events} events")
    return 0


def record(src, args: argparse.Namespace) -> tuple[int, float, int, int]:
    """Copy frames of ``src`` into ``args.out``; returns (frames, duration s, frames with ground truth, events)."""
    scale = args.depth_scale or getattr(src, "depth_scale", None) or 0.001
    parts = list(getattr(src, "parts", None) or [])
    poses = dict(getattr(src, "initial_poses", None) or {})
    n = n_gt = 0
    t0 = t_last = None
    with RecordingWriter(args.out, src.intrinsics, depth_scale=scale, parts=parts, initial_poses=poses,
                         color_format=args.color_format, overwrite=args.overwrite) as writer:
        it = iter(src)
        try:
            while args.frames is None or n < args.frames:
                try:
                    frame = next(it)
                except StopIteration:
                    break
                except SourceError as exc:  # a corrupt frame in a recording: skip it
                    log.warning("skipping a frame: %s", exc)
                    continue
                if t0 is None:
                    t0 = frame.timestamp
                if args.seconds is not None and frame.timestamp - t0 > args.seconds:
                    break
                gt = frame.meta.get("groundtruth")
                writer.write(frame, groundtruth=gt if gt and gt.get("poses") is not None else None)
                n_gt += gt is not None and gt.get("poses") is not None
                n += 1
                t_last = frame.timestamp
        except KeyboardInterrupt:
            log.info("interrupted: closing the recording")
        n_events = 0
        if t_last is not None:
            for ev in getattr(src, "events", None) or []:
                if ev.t <= t_last:
                    writer.write_event(ev.t, ev.type, ev.parts)
                    n_events += 1
    if n == 0:
        raise SourceError(f"{args.source}: no frames recorded")
    return n, (t_last - t0) if t_last is not None else 0.0, n_gt, n_events
