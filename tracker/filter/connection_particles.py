"""Connection-aware particles (spec section 9, Algorithm 6 corrected).

For each connection k (first part a, second part b, desired pose of b in a's body frame (p_des, R_des)),
the leading N_k particles are forced onto the connection right after the transition step:

* forward pass over the connections in order, particles j = 1, 3, 5, … ≤ N_k (0-based 0, 2, 4, …):
  r_b ← (p_a + R_a p_des, R_a R_des);
* backward pass in reverse order, particles j = 2, 4, 6, … ≤ N_k (0-based 1, 3, 5, …):
  r_a ← (p_b − R_b R_desᵀ p_des, R_b R_desᵀ).

Choices (spec leaves them open): the velocities of forced particles are left as sampled; a locked
connection uses its hint's N_k (the monitor passes N_max); overflow rule: every N_k is clipped to
``max_fraction · N`` so that at least the remaining particles always stay free (all connections share the
leading particles, so Σ N_k may exceed N without harm otherwise).

Visibility gate (choice documented here; TrackerConfig ``hint_min_visibility``): a connection that is not yet
locked forces a part only when the tracker estimates that part as visible enough (``forceable``). A part
hidden by the hand cannot be judged by the depth image, so a forced hypothesis "next to its neighbour" costs
it nothing and could win against the true, hidden position: the cube would jump onto the neighbour seconds
before the user places it. Locked connections always force both parts (a hidden cube of an established
structure stays with it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ResolvedConnection:
    """A connection hint with part indices: a = first, b = second, pose of b in a's frame, N_k."""

    a: int
    b: int
    p_des: np.ndarray
    R_des: np.ndarray
    n_k: int
    locked: bool = False


def resolve_hints(hints, names: list[str], n_particles: int, max_fraction: float) -> list[ResolvedConnection]:
    """Turn :class:`ConnectionHint` objects into index form (clear errors on bad names)."""
    index = {n: i for i, n in enumerate(names)}
    cap = int(np.floor(max_fraction * n_particles))
    out = []
    for h in hints:
        for nm in (h.first, h.second):
            if nm not in index:
                raise ValueError(f"connection hint names unknown part {nm!r}; tracked parts: {names}")
        if h.first == h.second:
            raise ValueError(f"connection hint connects part {h.first!r} to itself")
        n_k = int(min(max(int(h.n_particles), 0), cap))
        if n_k <= 0:
            continue
        out.append(ResolvedConnection(index[h.first], index[h.second], h.relative.t.copy(), h.relative.R.copy(), n_k,
                                      bool(getattr(h, "locked", False))))
    return out


def apply_connections(p: np.ndarray, R: np.ndarray, conns: list[ResolvedConnection],
                      forceable: np.ndarray | None = None) -> np.ndarray:
    """Force the leading particles onto their connections in place (Algorithm 6); returns the changed mask (N, K).

    ``p`` (N, K, 3) positions and ``R`` (N, K, 3, 3) rotations in the camera frame. ``forceable`` (K,) bool:
    parts that unlocked connections may move (None = all); locked connections move any part.
    """
    changed = np.zeros(p.shape[:2], bool)

    def allowed(c: ResolvedConnection, part: int) -> bool:
        return c.locked or forceable is None or bool(forceable[part])

    for c in conns:  # forward pass: odd particles (1-based) take the second part from the first
        if not allowed(c, c.b):
            continue
        idx = np.arange(0, min(c.n_k, p.shape[0]), 2)
        p[idx, c.b] = p[idx, c.a] + R[idx, c.a] @ c.p_des
        R[idx, c.b] = R[idx, c.a] @ c.R_des
        changed[idx, c.b] = True
    for c in reversed(conns):  # backward pass: even particles take the first part from the second
        if not allowed(c, c.a):
            continue
        idx = np.arange(1, min(c.n_k, p.shape[0]), 2)
        Rt = c.R_des.T
        p[idx, c.a] = p[idx, c.b] - R[idx, c.b] @ (Rt @ c.p_des)
        R[idx, c.a] = R[idx, c.b] @ Rt
        changed[idx, c.a] = True
    return changed
