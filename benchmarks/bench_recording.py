"""Benchmark of the recording reader/writer and the depth-to-colour registration (640×480).

Prints the figures and writes benchmarks/results/recording.json and benchmarks/results/recording.md.
Run: ``.venv/bin/python benchmarks/bench_recording.py``.
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from tracker.evaluation.machine_info import machine_info
from tracker.frame import Frame
from tracker.geometry.camera import Intrinsics
from tracker.shared_data import shared_root
from tracker.sources.depth_registration import register_depth
from tracker.sources.recording import RecordingSource, RecordingWriter

RESULTS = Path(__file__).resolve().parent / "results"
REAL = shared_root() / "data" / "real" / "visp-cube-desk"




def timed(fn, repeat: int) -> float:
    """Median milliseconds of ``repeat`` calls (after one warm-up call)."""
    fn()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1000.0)
    return float(np.median(times))


def main() -> None:
    rng = np.random.default_rng(0)
    intr = Intrinsics.default()
    n = 20
    # smooth-ish synthetic content so PNG compression behaves like a real scene
    base = rng.integers(0, 256, size=(60, 80, 3), dtype=np.uint8)
    color = np.kron(base, np.ones((8, 8, 1), np.uint8))
    depth = (0.8 + 0.2 * np.sin(np.mgrid[0:480, 0:640][1] / 50.0)).astype(np.float32)
    depth[::7, ::5] = np.nan
    frames = [Frame(i, i / 30.0, color, depth, intr) for i in range(n)]
    out: dict[str, float | int | str] = {}
    with tempfile.TemporaryDirectory() as tmp:
        t = time.perf_counter()
        with RecordingWriter(Path(tmp) / "rec", intr) as w:
            for f in frames:
                w.write(f)
        out["write_ms_per_frame"] = (time.perf_counter() - t) * 1000.0 / n
        src = RecordingSource(Path(tmp) / "rec")
        t = time.perf_counter()
        for _ in src:
            pass
        out["read_ms_per_frame"] = (time.perf_counter() - t) * 1000.0 / n
    real = RecordingSource(REAL)
    out["read_real_visp_ms_per_frame"] = timed(lambda: real.read(3), 10)

    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [0.5, -1.0, 0.2], degrees=True).as_matrix()
    T[:3, 3] = [0.015, 0.0, 0.0]
    for name, dint in (("640x480", Intrinsics(640, 480, 385.0, 385.0, 320.0, 240.0)),
                       ("848x480", Intrinsics(848, 480, 420.0, 420.0, 424.0, 240.0))):
        d = rng.uniform(0.5, 1.5, size=(dint.height, dint.width)).astype(np.float32)
        out[f"register_depth_{name}_to_640x480_ms"] = timed(lambda d=d, dint=dint: register_depth(
            d, dint, Intrinsics(640, 480, 615.0, 615.0, 320.0, 240.0), T), 10)

    out.update(machine_info())
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "recording.json").write_text(json.dumps(out, indent=2) + "\n")
    lines = [
        "## Recordings and depth registration",
        "",
        f"Machine: {out['nproc']} cores, {out['cpu']}. The machine was shared with other jobs while measuring, "
        "so the figures are pessimistic.",
        "",
        "| Operation (640×480) | ms |",
        "|---|---|",
        f"| write one frame (PNG colour + 16-bit PNG depth) | {out['write_ms_per_frame']:.1f} |",
        f"| read one frame (decode, depth → metres) | {out['read_ms_per_frame']:.1f} |",
        f"| read one real frame (visp-cube-desk) | {out['read_real_visp_ms_per_frame']:.1f} |",
        f"| register depth 640×480 → colour 640×480 | {out['register_depth_640x480_to_640x480_ms']:.1f} |",
        f"| register depth 848×480 → colour 640×480 | {out['register_depth_848x480_to_640x480_ms']:.1f} |",
        "",
    ]
    (RESULTS / "recording.md").write_text("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
