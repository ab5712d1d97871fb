"""``assembly-agent simulate``: list the simulated scenarios or write one as a recording."""

from __future__ import annotations

import argparse
import time


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "simulate",
        help="list simulated scenarios or write one as a recording",
        description="Render a scripted scenario of the simulated RGB-D table and write it as a recording "
        "(colour, depth, ground-truth poses, connection events). Use --list to see the scenarios.",
    )
    p.add_argument("scenario", nargs="?", help="scenario name (see --list)")
    p.add_argument("--list", action="store_true", help="print the scenarios with one-line descriptions")
    p.add_argument("--out", help="output recording directory")
    p.add_argument("--seed", type=int, default=0, help="random seed (same seed → identical frames; default 0)")
    p.add_argument("--frames", type=int, default=None, help="number of frames to write (default: whole scenario)")
    p.add_argument("--speed", type=float, default=1.0, help="hand motion speed factor (default 1.0)")
    p.add_argument("--occlusion", type=float, default=1.0, help="amount of hand occlusion 0..2 (default 1.0)")
    p.add_argument("--excursions", action="store_true", help="carry parts briefly out of view before placing")
    p.add_argument("--camera-motion", default="none", choices=("none", "sway", "handheld"),
                   help="camera motion: none (fixed), sway (slow, a few cm / degrees) or handheld (sway plus "
                        "jitter); the ground truth of each frame is in its own camera frame (default none)")
    p.add_argument("--rod", action="store_true", help="add a grey 2×2×10 cm rod lying on the table")
    p.add_argument(
        "--mesh",
        action="append",
        default=[],
        metavar="PATH[:SCALE]",
        help="add a rigid mesh part (OBJ/PLY/STL, SCALE to metres, default 1) lying on the table; repeatable",
    )
    p.add_argument("--overwrite", action="store_true", help="replace an existing recording in --out")
    p.set_defaults(func=run)


def extra_parts(args: argparse.Namespace) -> tuple:
    """PartSpecs of --rod and --mesh PATH[:SCALE]."""
    from pathlib import Path

    from tracker.geometry.parts import ROD_SIZE, PartSpec

    parts = []
    if getattr(args, "rod", False):
        parts.append(PartSpec("rod", box=ROD_SIZE, color=(170, 170, 175)))
    for i, spec in enumerate(getattr(args, "mesh", None) or []):
        path, _, scale = spec.partition(":")
        try:
            factor = float(scale) if scale else 1.0
        except ValueError:
            raise ValueError(f"--mesh {spec!r}: SCALE must be a number") from None
        if not Path(path).is_file():
            raise ValueError(f"--mesh {spec!r}: mesh file not found: {path}")
        parts.append(PartSpec(f"mesh{i + 1}", box=None, mesh=path, mesh_scale=factor, color=(150, 150, 160)))
    return tuple(parts)


def run(args: argparse.Namespace) -> int:
    from tracker.sources.simulator import SimOptions, SimulatedTable, list_scenarios

    if args.list:
        scenarios = list_scenarios()
        width = max(len(s.name) for s in scenarios)
        for s in scenarios:
            print(f"{s.name:<{width}}  {s.description}")
        return 0
    if not args.scenario:
        raise ValueError("give a scenario name (see `assembly-agent simulate --list`)")
    if not args.out:
        raise ValueError("give --out DIR, the recording directory to write")
    if args.frames is not None and args.frames < 1:
        raise ValueError(f"--frames must be at least 1, got {args.frames}")

    from tracker.sources.recording import RecordingWriter

    opts = SimOptions(
        speed=args.speed,
        occlusion=args.occlusion,
        excursions=args.excursions,
        extra_parts=extra_parts(args),
        camera_motion=getattr(args, "camera_motion", "none"),
    )
    src = SimulatedTable(args.scenario, seed=args.seed, options=opts, realtime=False, n_frames=args.frames)
    start = time.perf_counter()
    writer = RecordingWriter(
        args.out,
        src.intrinsics,
        depth_scale=0.001,
        parts=src.parts,
        initial_poses=src.initial_poses,
        overwrite=args.overwrite,
    )
    n = 0
    from tqdm import tqdm

    with writer, src, tqdm(total=len(src), unit="frame", desc=args.scenario, disable=None) as bar:
        for frame in src:
            writer.write(frame, groundtruth=frame.meta["groundtruth"])
            n += 1
            bar.update(1)
        t_end = n / 30.0
        events = [e for e in src.events if e.t < t_end]
        for e in events:
            writer.write_event(e.t, e.type, e.parts)
    elapsed = time.perf_counter() - start
    print(
        f"wrote {args.out}: scenario {args.scenario} (seed {args.seed}), {n} frames "
        f"({n / 30.0:.1f} s at 30 fps) in {elapsed:.1f} s"
    )
    print(f"  camera: {src.camera.distance:.3f} m from the table centre, {src.camera.elevation_deg:.1f}° down"
          + (f", moving ({src.camera_motion})" if src.camera_motion != "none" else ""))
    print(f"  parts ({len(src.parts)}): {', '.join(p.name for p in src.parts)}")
    print(f"  events ({len(events)}):")
    for e in events:
        print(f"    {e.t:7.2f} s  {e.type:<12} {e.parts[0]} – {e.parts[1]}")
    return 0
