"""Trajectories in the TUM RGB-D benchmark text format (Sturm et al., IROS 2012): one line per pose,
``timestamp tx ty tz qx qy qz qw`` — the camera's pose in the world frame (camera → world; metres, Hamilton
quaternion), timestamp in seconds. Lines starting with ``#`` are comments; our writer flags poses that were not
measured (extrapolated) with a comment on the line before them."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from tracker.geometry.pose import Pose


def format_tum_line(timestamp: float, pose: Pose) -> str:
    """One TUM line of a pose (camera → world)."""
    vals = [float(timestamp), *(float(v) for v in pose.t), *(float(v) for v in pose.q)]
    return f"{vals[0]:.6f} " + " ".join(f"{v:.9f}" for v in vals[1:])


def write_tum(path: str | Path, rows: Iterable[tuple], header: str = "") -> int:
    """Write ``(timestamp, pose)`` or ``(timestamp, pose, note)`` rows; returns how many. ``header`` lines and
    non-empty notes (written on the line before their pose) are ``#`` comments."""
    n = 0
    with open(path, "w", encoding="utf-8") as fh:
        for line in header.splitlines():
            fh.write(f"# {line}\n")
        for row in rows:
            ts, pose = row[0], row[1]
            note = row[2] if len(row) > 2 else ""
            if note:
                fh.write(f"# {' '.join(str(note).split())}\n")
            fh.write(format_tum_line(ts, pose) + "\n")
            n += 1
    return n


def read_tum(path: str | Path) -> tuple[np.ndarray, list[Pose]]:
    """``(timestamps, poses)`` of a TUM trajectory file; ValueError naming the line for malformed input."""
    times: list[float] = []
    poses: list[Pose] = []
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError as exc:
        raise ValueError(f"{path}: file not found") from exc
    for lineno, line in enumerate(text.splitlines(), start=1):
        s = line.strip()
        if not s or s.startswith("#"):
            continue
        parts = s.split("#", 1)[0].split()
        if len(parts) != 8:
            raise ValueError(f"{path}, line {lineno}: expected 8 numbers 'timestamp tx ty tz qx qy qz qw', "
                             f"got {len(parts)}")
        try:
            v = [float(x) for x in parts]
            pose = Pose(np.array(v[1:4]), np.array(v[4:8]))
        except ValueError as exc:
            raise ValueError(f"{path}, line {lineno}: {exc}") from exc
        times.append(v[0])
        poses.append(pose)
    return np.asarray(times, dtype=np.float64), poses
