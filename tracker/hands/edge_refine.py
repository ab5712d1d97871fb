"""A reported hand box's colour edges placed at full resolution (product addition, ``HandTrackerConfig.edge_refine``).

The tracker works on the frame downscaled by ``scale`` (2: 2 × 2 blocks averaged), so every box it reports ends on a
working pixel, and a block that holds only part of the hand's rim takes the mixed colour of skin and background: on
a shaded rim (the side away from the light) that mixture falls outside the skin model and the block is lost. Traced
on ``hands-s1`` tuning seeds 0–4 (ground-truth start, filter seed 0): the full-resolution colour mask's tight box of
the hand matches the ground-truth palm box within a pixel, but the working mask's is short by 1.1–1.9 px on the
right edge and 0.5–0.6 px on the bottom one, so every box's centre lay 0.4–0.75 px left of and 0.2–0.4 px above the
ground truth's.

Each edge of the reported box is moved to the last full-resolution skin pixel within ``grow`` px of it on either side
(the skin of the box's own rows for the left and right edges, of its own columns for the top and bottom ones), but
only where the edge is a colour edge: if the skin goes on at ``grow`` px beyond the edge (a wrist cut of a bare
forearm, the other hand touching this one, or the image border there) the edge is kept, and so it is when no skin
lies within ``grow`` px of it. With :data:`ALL_ENDS` (on) a box is refined only when all four edges are colour edges.
Session 30, tuning seeds 0–4, filter seed 0, the same frames for both arms, off → on: ``hands-s1`` ground-truth start
F̄^b 0.9846 → 0.9971, ē^p 0.855 → 0.245 px, automatic start 0.9825 → 0.9949, 1.063 → 0.453 px; ``hands-s2``
ground-truth start 0.8925 → 0.8967, 6.56 → 6.38 px, KF 0.8917 → 0.8960; ``hands-s3`` identical (a bare forearm's
wrist edge is a cut); missed hands and false boxes equal (``benchmarks/history/issue-14-hands.md``).

Boxes are end-exclusive full-resolution pixel boxes [u0, v0, u1, v1].
"""

from __future__ import annotations

import numpy as np

GROW_WORKING = 1
"""Working px (times the tracker's scale: full px) within which an edge moves to the full-resolution skin."""
ALL_ENDS = True
"""Whether a box is refined only when all four of its edges are colour edges (the hand's whole skin lies within the
box's band: a sleeved hand on its own). Off, each colour edge moves by itself: on ``hands-s3`` (bare forearms, the
wrist edge a cut) the other edges then also moved onto skin-like parts next to a box that already held one.
Measured in ``benchmarks/history/issue-14-hands.md`` (session 30)."""


def _edge(any_skin: np.ndarray, origin: int, edge: int, grow: int, far: bool) -> int | None:
    """New position of one edge along one axis, or None where it is not a colour edge. ``any_skin[i]``: whether line
    ``origin + i`` (a column or a row of the crop) holds skin within the box's span; ``edge``: the end-exclusive far
    edge (``far``) or the first line of the near edge; both full-resolution pixels."""
    n = len(any_skin)
    if far:
        beyond, lo, hi = edge + grow, edge - grow, edge + grow
    else:
        beyond, lo, hi = edge - grow - 1, edge - grow, edge + grow
    if not 0 <= beyond - origin < n or any_skin[beyond - origin]:
        return None  # at the image border, or the skin goes on: not a colour edge
    lines = np.flatnonzero(any_skin[max(lo - origin, 0) : max(hi - origin, 0)])
    if len(lines) == 0:
        return edge
    first = max(lo - origin, 0) + origin
    return int(first + lines[-1] + 1) if far else int(first + lines[0])


def refine_box(box, mask_of, size: tuple[int, int], grow: int) -> list[int]:
    """``box`` (end-exclusive [u0, v0, u1, v1], full-resolution px) with its colour edges moved to the
    full-resolution skin within ``grow`` px (see the module docstring). ``mask_of(x0, y0, x1, y1)`` returns the
    full-resolution colour mask (H×W of 0/1 or bool) of the image crop [y0:y1, x0:x1]; ``size`` (W, H) the image's.
    An empty box, or one whose refined edges would cross, is returned unchanged."""
    u0, v0, u1, v1 = (int(b) for b in box)
    W, H = size
    if u1 <= u0 or v1 <= v0 or grow < 1:
        return [u0, v0, u1, v1]
    x0, y0 = max(u0 - grow - 1, 0), max(v0 - grow - 1, 0)
    x1, y1 = min(u1 + grow + 1, W), min(v1 + grow + 1, H)
    m = np.asarray(mask_of(x0, y0, x1, y1), bool)
    cols = m[v0 - y0 : v1 - y0, :].any(axis=0)
    rows = m[:, u0 - x0 : u1 - x0].any(axis=1)
    n0, n1 = _edge(cols, x0, u0, grow, far=False), _edge(cols, x0, u1, grow, far=True)
    m0, m1 = _edge(rows, y0, v0, grow, far=False), _edge(rows, y0, v1, grow, far=True)
    if ALL_ENDS and None in (n0, n1, m0, m1):
        return [u0, v0, u1, v1]
    n0, n1 = u0 if n0 is None else n0, u1 if n1 is None else n1
    m0, m1 = v0 if m0 is None else m0, v1 if m1 is None else m1
    if n1 <= n0 or m1 <= m0:
        return [u0, v0, u1, v1]
    return [n0, m0, n1, m1]
