"""``assembly-agent hands RECORDING --out FILE``: track the hands in a recording's colour frames.

Runs :class:`tracker.hands.tracker.HandTracker` (the seed-004 particle filter, or ``--method kalman`` for the
thesis's Kalman reference) with automatic track start and termination, and writes one JSON line per frame::

    {"index": i, "t": seconds, "hands": [{"id": 1, "box": [u0, v0, u1, v1], "score": 0.83}]}

``box`` is the hand's (palm's) box in end-exclusive colour-image pixels, ``id`` a track id stable over time,
``score`` the box's colour coverage a_{c,1} (0..1). A frame that cannot be read is reported on stderr and skipped
(its line is not written); the others are still tracked and written, and the command then exits with status 1.
"""

from __future__ import annotations

import argparse
import json
import sys
import time


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "hands",
        help="track the hands in a recording (skin colour + optical flow particle filter)",
        description="Track up to two hands in the colour frames of a recording and write one JSON line per frame "
        "with each hand's id, box [u0, v0, u1, v1] (end-exclusive pixels) and score.",
    )
    p.add_argument("recording", help="recording directory (README 'Recording format')")
    p.add_argument("--out", required=True, help="output JSON-lines file")
    p.add_argument("--method", choices=("pf", "kalman"), default="pf",
                   help="particle filter (default) or the Kalman-filter reference")
    p.add_argument("--particles", type=int, default=30, help="number of particles N_s (default 30; N_T = N_s/2)")
    p.add_argument("--flow", choices=("dis", "dis-fast", "farneback"), default="dis",
                   help="dense optical flow (default dis)")
    p.add_argument("--frames", type=int, default=None, help="stop after this many frames")
    p.add_argument("--seed", type=int, default=0, help="random seed of the particle filter")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from tracker.hands.tracker import HandTracker, HandTrackerConfig
    from tracker.sources.base import SourceError
    from tracker.sources.recording import RecordingSource

    if args.particles < 1:
        raise ValueError(f"--particles must be at least 1, got {args.particles}")
    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames must be at least 1, got {args.frames}")
    import cv2

    cv2.setNumThreads(1)  # one core, as the server's hand process: the spec's budget is per frame on one core
    cfg = HandTrackerConfig(method=args.method, n_particles=args.particles, flow=args.flow, seed=args.seed)
    src = RecordingSource(args.recording)
    tracker = HandTracker(cfg, focal=src.intrinsics.fx)
    it = iter(src)
    n = 0
    bad: list[str] = []
    ids: set[int] = set()
    t_track = 0.0
    t0 = time.perf_counter()
    with open(args.out, "w", encoding="utf-8") as out, src:
        while args.frames is None or n < args.frames:
            try:
                frame = next(it)
            except StopIteration:
                break
            except SourceError as exc:
                bad.append(str(exc))
                print(f"assembly-agent hands: skipped a frame: {exc}", file=sys.stderr)
                continue
            t1 = time.perf_counter()
            hands = tracker.process(frame.color, frame.depth)
            t_track += time.perf_counter() - t1
            ids.update(h.id for h in hands)
            out.write(json.dumps({"index": frame.index, "t": round(float(frame.timestamp), 6),
                                  "hands": [h.to_dict() for h in hands]}) + "\n")  # fmt: skip
            out.flush()
            n += 1
    wall = time.perf_counter() - t0
    if n == 0:
        raise RuntimeError(f"{args.recording}: no frame could be read" + (f" ({bad[0]})" if bad else ""))
    print(f"tracked {n} frames: {len(ids)} hand track(s); hand tracker {n / max(t_track, 1e-9):.1f} fps "
          f"({1000 * t_track / n:.1f} ms/frame), overall with decoding {n / max(wall, 1e-9):.1f} fps; "
          f"written to {args.out}")
    if bad:
        print(f"assembly-agent hands: error: {len(bad)} frame(s) could not be read and were skipped", file=sys.stderr)
        return 1
    return 0
