"""Symmetry-aware pose errors and their summaries (translation in metres, rotation in radians).

Rotation error of a part is the smallest angle over its symmetry group (24 rotations for a cube, 4 for a box
with distinct sides, see :mod:`tracker.geometry.symmetry`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose
from tracker.geometry.symmetry import symmetric_rotation_error, symmetry_group


@dataclass
class PoseErrorLog:
    """Per-part lists of translation (m) and rotation (rad) errors, filled frame by frame."""

    parts: list[PartSpec]
    translation: dict[str, list[float]] = field(default_factory=dict)
    rotation: dict[str, list[float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._groups = {p.name: symmetry_group(p) for p in self.parts}
        for p in self.parts:
            self.translation.setdefault(p.name, [])
            self.rotation.setdefault(p.name, [])

    def add(self, estimates: dict[str, Pose], truth: dict[str, Pose]) -> None:
        """Record the errors of every part present in both dicts."""
        for name, g in self._groups.items():
            if name in estimates and name in truth:
                e, t = estimates[name], truth[name]
                self.translation[name].append(float(np.linalg.norm(e.t - t.t)))
                self.rotation[name].append(float(symmetric_rotation_error(e.R, t.R, g)))

    def summary(self) -> dict[str, dict[str, float]]:
        """Per part and "all": translation mm and rotation degrees, mean / median / p95 / max, and frame count."""
        out: dict[str, dict[str, float]] = {}
        names = list(self._groups) + ["all"]
        for name in names:
            if name == "all":
                t = np.concatenate([np.asarray(v) for v in self.translation.values()] or [np.zeros(0)])
                r = np.concatenate([np.asarray(v) for v in self.rotation.values()] or [np.zeros(0)])
            else:
                t, r = np.asarray(self.translation[name]), np.asarray(self.rotation[name])
            if t.size == 0:
                continue
            t_mm, r_deg = t * 1000.0, np.degrees(r)
            out[name] = {
                "frames": int(t.size),
                "t_mean_mm": float(t_mm.mean()),
                "t_median_mm": float(np.median(t_mm)),
                "t_p95_mm": float(np.percentile(t_mm, 95)),
                "t_max_mm": float(t_mm.max()),
                "r_mean_deg": float(r_deg.mean()),
                "r_median_deg": float(np.median(r_deg)),
                "r_p95_deg": float(np.percentile(r_deg, 95)),
            }
        return out


def format_summary(summary: dict[str, dict[str, float]]) -> str:
    """Fixed-width table of :meth:`PoseErrorLog.summary`."""
    lines = [f"{'part':10s} {'frames':>6s} | {'t mean':>7s} {'median':>7s} {'p95':>7s} mm | "
             f"{'r mean':>7s} {'median':>7s} {'p95':>7s} deg"]
    for name, s in summary.items():
        lines.append(
            f"{name:10s} {s['frames']:6d} | {s['t_mean_mm']:7.2f} {s['t_median_mm']:7.2f} {s['t_p95_mm']:7.2f}    | "
            f"{s['r_mean_deg']:7.2f} {s['r_median_deg']:7.2f} {s['r_p95_deg']:7.2f}"
        )
    return "\n".join(lines)


LOST_T = 0.05
"""Metres: a part whose translation error exceeds this (or whose rotation error exceeds ``LOST_R``) …"""
LOST_R = float(np.radians(30.0))
"""Radians (symmetry-aware rotation error)."""
LOST_FRAMES = 10
"""… for at least this many consecutive frames is lost."""


def lost_runs(log: PoseErrorLog, t_max: float = LOST_T, r_max: float = LOST_R,
              min_frames: int = LOST_FRAMES) -> dict[str, int]:
    """Per part, the number of runs of ≥ ``min_frames`` consecutive logged frames with translation error >
    ``t_max`` (m) or symmetry-aware rotation error > ``r_max`` (rad), whether the part is visible or not. A part
    with at least one such run counts as lost."""
    out: dict[str, int] = {}
    for name in log.translation:
        bad = (np.asarray(log.translation[name]) > t_max) | (np.asarray(log.rotation[name]) > r_max)
        runs = run = 0
        for b in bad:
            run = run + 1 if b else 0
            runs += run == min_frames
        out[name] = runs
    return out
