"""What the tracker's stages share within one frame, and what the coordinate passes hand back."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tracker.frame import Frame


@dataclass
class FrameContext:
    """One frame as the filter's stages see it (camera frame, metres, seconds).

    ``table``: what the caller passed (TablePlane-like or ``(normal, offset)``); ``table_plane``: it as a unit
    ``(normal, offset)`` or None; ``timings``: milliseconds per stage; ``t0``: ``perf_counter`` at the start;
    ``occluders``: full-resolution bool H×W of pixels known to show an occluder in front of the parts (the hand
    tracker's mask H_k, hand-tracking spec §14.5) or None: the weighing raises the predicted occlusion probability
    there to at least ``occluder_probability`` (o_hand) and the refinement leaves those pixels out; ``touched``: parts
    a tracked hand touches (hand-tracking spec §14.6): the hand carry may take such a part along when it vanishes."""

    frame: Frame
    table: Any
    table_plane: tuple[np.ndarray, float] | None
    t0: float
    timings: dict[str, float] = field(default_factory=dict)
    occluders: np.ndarray | None = None
    occluder_probability: float = 0.9
    touched: frozenset[str] = frozenset()

    @property
    def depth(self) -> np.ndarray | None:
        return self.frame.depth

    @property
    def now(self) -> float:
        return float(self.frame.timestamp)

    def occluder_prior(self, us: np.ndarray, vs: np.ndarray, gi: np.ndarray, gj: np.ndarray) -> np.ndarray | None:
        """o_hand · H_i (float32, one per evaluated grid pixel, hand-tracking spec §14.5) for the grid pixels
        ``(us[gi], vs[gj])`` of a grid with step f = us[1] − us[0] whose block (gj, gi) covers the full-resolution
        pixels [f·gj, f·gj + f) × [f·gi, f·gi + f): H_i = 1 when any pixel of the block is an occluder (max-pooling);
        None without occluders."""
        occ = self.occluders
        if occ is None:
            return None
        f = int(us[1] - us[0]) if len(us) > 1 else 1
        nv, nu = len(vs), len(us)
        padded = np.zeros((nv * f, nu * f), bool)
        h, w = min(occ.shape[0], nv * f), min(occ.shape[1], nu * f)
        padded[:h, :w] = occ[:h, :w]
        pooled = padded.reshape(nv, f, nu, f).any(axis=(1, 3))
        return np.float32(self.occluder_probability) * pooled[gj, gi].astype(np.float32)

    @property
    def refine_depth(self) -> np.ndarray | None:
        """The depth image for the refinement: NaN (no measurement) at the occluder pixels, else the frame's."""
        d = self.frame.depth
        if d is None or self.occluders is None:
            return d
        return np.where(self.occluders, np.float32(np.nan), d)


@dataclass
class PassResult:
    """The particles after the coordinate passes (:mod:`tracker.filter.weigh`) and what the occlusion update needs.

    ``p`` (N, K, 3), ``R`` (N, K, 3, 3), ``v`` (N, K, 6): particles; ``log_w`` (N,) log weights; ``ell`` (N,)
    penalised log-likelihood of the last pass; ``pix`` evaluated grid pixels; ``Q``, ``F``, ``o_hat``, ``anc``:
    per-particle occlusion terms and ancestors; ``n_resampled``: passes that resampled."""

    p: np.ndarray
    R: np.ndarray
    v: np.ndarray
    log_w: np.ndarray
    ell: np.ndarray
    pix: np.ndarray
    Q: np.ndarray
    F: np.ndarray
    o_hat: np.ndarray
    anc: np.ndarray
    n_resampled: int


def table_normal_offset(table) -> tuple[np.ndarray, float] | None:
    """(normal, offset) of a TablePlane-like object or a ``(normal, offset)`` tuple; None when absent."""
    if table is None:
        return None
    if hasattr(table, "normal") and hasattr(table, "offset"):
        n, off = table.normal, table.offset
    else:
        n, off = table
    n = np.asarray(n, np.float64).reshape(3)
    norm = np.linalg.norm(n)
    if not np.isfinite(norm) or norm < 1e-9:
        raise ValueError("table plane normal must be a non-zero finite vector")
    return n / norm, float(off) / norm
