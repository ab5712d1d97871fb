"""``assembly-agent inspect``: perception on one frame of a recording, printed as JSON.

* ``inspect table RECORDING [--frame N] [--outline]``: the table plane in the camera frame,
  ``{"normal": [nx, ny, nz], "offset": d, "inlier_fraction": f, "residual_rms": r, "n_points": n}`` where points
  p on the plane satisfy ``normal·p + offset = 0`` (metres; normal pointing up toward the camera).
* ``inspect colors RECORDING [--frame N] [--colors red,green,...] [--calibrate NAME=x,y,w,h ...]``: colour
  detections of the recording's coloured parts (objects.json), or of the named preset colours (default: all
  presets), optionally with ranges calibrated on rectangles of that frame. Prints the ranges and detections.
"""

from __future__ import annotations

import argparse
import json

from tracker.geometry.parts import PRESET_COLORS
from tracker.perception.color_detection import ColorDetector, calibrate_range


def register(subparsers) -> None:
    p = subparsers.add_parser("inspect", help="print the table plane or colour detections of a recording frame")
    sub = p.add_subparsers(dest="what", metavar="WHAT", required=True)
    t = sub.add_parser("table", help="table plane of a frame as JSON (camera frame, normal·p + offset = 0)")
    t.add_argument("recording", help="recording directory")
    t.add_argument("--frame", type=int, default=0, help="frame position in frames.jsonl (default 0)")
    t.add_argument("--outline", action="store_true", help="also print the table outline polygon (pixels)")
    t.set_defaults(func=run)
    c = sub.add_parser("colors", help="colour detections of a frame as JSON")
    c.add_argument("recording", help="recording directory")
    c.add_argument("--frame", type=int, default=0, help="frame position in frames.jsonl (default 0)")
    c.add_argument("--colors", default=None, help="comma-separated preset colour names (default: the recording's "
                   "coloured parts, else all presets)")
    c.add_argument("--calibrate", action="append", default=[], metavar="NAME=x,y,w,h",
                   help="calibrate NAME's range on this rectangle of the frame (repeatable)")
    c.set_defaults(func=run)


def _open_frame(path: str, position: int):
    from tracker.sources.recording import RecordingSource

    src = RecordingSource(path)
    try:
        return src, src.read(position)
    except IndexError as exc:
        raise ValueError(str(exc)) from exc


def _parse_calibration(spec: str) -> tuple[str, tuple[int, ...]]:
    name, sep, rect = spec.partition("=")
    try:
        vals = tuple(int(round(float(v))) for v in rect.split(","))
    except ValueError:
        vals = ()
    if not sep or not name or len(vals) != 4:
        raise ValueError(f"--calibrate expects NAME=x,y,w,h, got {spec!r}")
    return name, vals


def run(args: argparse.Namespace) -> int:
    src, frame = _open_frame(args.recording, args.frame)
    if args.what == "table":
        from tracker.perception.table_plane import detect_table

        if frame.depth is None:
            raise ValueError(f"{args.recording}: frame {frame.index} has no depth image")
        plane = detect_table(frame.depth, frame.intrinsics)
        print(json.dumps(plane.to_dict(with_outline=args.outline)))
        return 0
    # colours
    if args.colors:
        names = [c.strip() for c in args.colors.split(",") if c.strip()]
        detector = ColorDetector.from_parts(names)
    else:
        coloured = [p for p in src.parts if p.color is not None or p.name in PRESET_COLORS]
        detector = ColorDetector.from_parts(coloured if coloured else list(PRESET_COLORS))
    for spec in args.calibrate:
        name, rect = _parse_calibration(spec)
        detector.ranges[name] = calibrate_range(frame.color, rect)
    dets = detector.detect(frame.color)
    out = {
        "frame": frame.index,
        "ranges": {n: r.to_dict() for n, r in detector.ranges.items()},
        "detections": {n: d.to_dict() for n, d in dets.items()},
    }
    print(json.dumps(out))
    return 0
