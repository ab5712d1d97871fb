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
    ``(normal, offset)`` or None; ``timings``: milliseconds per stage; ``t0``: ``perf_counter`` at the start."""

    frame: Frame
    table: Any
    table_plane: tuple[np.ndarray, float] | None
    t0: float
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def depth(self) -> np.ndarray | None:
        return self.frame.depth

    @property
    def now(self) -> float:
        return float(self.frame.timestamp)


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
