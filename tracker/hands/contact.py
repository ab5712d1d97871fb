"""Touching and holding between tracked hands and parts (hand-tracking spec §14.6).

Per frame the caller gives each hand's skin mask M^h_k (full-resolution bool H×W, e.g.
:meth:`tracker.hands.tracker.HandTracker.hand_masks`), each part's silhouette S_j at its estimated pose (bool H×W,
rendered by the cube tracker), optionally the measured depth and each part's rendered depth (metres, H×W, NaN or
0 where invalid), the parts' estimated positions (metres) and the image velocities (px/frame) of hands and parts.

* Contact test for hand h and part j: |dilate(M^h, r_touch) ∩ S_j| ≥ A_touch (r_touch = 3 px, A_touch = 20 px) and,
  where depth is valid, the median measured depth of the hand pixels within r_touch of S_j lies at most δ_touch = 3 cm
  behind and at most δ_front = 9 cm in front of the median rendered depth of S_j there. Product deviation from the
  spec's symmetric ±3 cm: a hand that grasps a cube from above shows the camera the back of the hand, measured 4–8 cm
  in front of the held cube's top in the simulator's guidance sessions, so the symmetric test never saw a grasp.
* Touching: the test held on ≥ 2 of the last 3 frames; it ends after n_off = 5 consecutive failing frames.
* Holding: touching, and either the part has moved ≥ 1.5 cm since touching began, or for 3 consecutive frames
  ‖v_part − v_hand‖ ≤ 0.5‖v_hand‖ with ‖v_hand‖ ≥ 2 px/frame.

:meth:`ContactMonitor.update` returns ``{(hand id, part name): "touching" | "holding"}`` for the current frame; the
connection gate of §14.7 needs only :meth:`ContactMonitor.touched_parts`.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import cv2
import numpy as np

from tracker.hands import order_stats

R_TOUCH = 3
A_TOUCH = 20
DELTA_TOUCH = 0.03
DELTA_FRONT = 0.09
N_OFF = 5
MOVE_HOLD = 0.015
N_VEL = 3

_TOUCH_KERNEL = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * R_TOUCH + 1, 2 * R_TOUCH + 1))
"""The disc of radius r_touch the contact test dilates with (made once; read only)."""


@dataclass
class _Pair:
    history: deque = field(default_factory=lambda: deque(maxlen=3))
    touching: bool = False
    fails: int = 0
    start_pos: np.ndarray | None = None
    vel_ok: int = 0
    holding: bool = False


def contact_test(hand_mask: np.ndarray, silhouette: np.ndarray, depth: np.ndarray | None = None,
                 part_depth: np.ndarray | None = None) -> bool:  # fmt: skip
    """The per-frame contact test of one hand and one part (see the module docstring)."""
    k = _TOUCH_KERNEL
    grown = cv2.dilate(hand_mask.astype(np.uint8), k).astype(bool)
    if np.count_nonzero(grown & silhouette) < A_TOUCH:
        return False
    if depth is None or part_depth is None:
        return True
    near_part = cv2.dilate(silhouette.astype(np.uint8), k).astype(bool)
    hand_px = depth[hand_mask & near_part]
    part_px = part_depth[silhouette & grown]
    hand_px = hand_px[np.isfinite(hand_px) & (hand_px > 0)]
    part_px = part_px[np.isfinite(part_px) & (part_px > 0)]
    if len(hand_px) == 0 or len(part_px) == 0:
        return True  # depth invalid there: test (ii) is skipped
    gap = order_stats.median(part_px) - order_stats.median(hand_px)  # > 0: the hand is in front of the part
    return -DELTA_TOUCH <= gap <= DELTA_FRONT


class ContactMonitor:
    """Touching / holding states with the hysteresis of §14.6, one per (hand id, part name) pair."""

    def __init__(self) -> None:
        self._pairs: dict[tuple[int, str], _Pair] = {}

    def update(self, hand_masks: dict[int, np.ndarray], silhouettes: dict[str, np.ndarray],
               part_positions: dict[str, np.ndarray] | None = None, depth: np.ndarray | None = None,
               part_depths: dict[str, np.ndarray] | None = None, hand_velocities: dict[int, np.ndarray] | None = None,
               part_velocities: dict[str, np.ndarray] | None = None) -> dict[tuple[int, str], str]:  # fmt: skip
        """States after this frame: ``{(hand, part): "touching" | "holding"}`` (pairs in neither state omitted)."""
        out: dict[tuple[int, str], str] = {}
        for key in set(self._pairs) | {(h, p) for h in hand_masks for p in silhouettes}:
            h, p = key
            st = self._pairs.setdefault(key, _Pair())
            hit = h in hand_masks and p in silhouettes and contact_test(
                hand_masks[h], silhouettes[p], depth, None if part_depths is None else part_depths.get(p))
            st.history.append(hit)
            if not st.touching and sum(st.history) >= 2:
                st.touching = True
                st.fails = 0
                st.vel_ok = 0
                st.holding = False
                st.start_pos = None if part_positions is None or p not in part_positions else \
                    np.asarray(part_positions[p], float).copy()
            elif st.touching:
                st.fails = 0 if hit else st.fails + 1
                if st.fails >= N_OFF:
                    st.touching = st.holding = False
            if st.touching and not st.holding:
                moved = (st.start_pos is not None and part_positions is not None and p in part_positions
                         and np.linalg.norm(np.asarray(part_positions[p]) - st.start_pos) >= MOVE_HOLD)  # fmt: skip
                vh = None if hand_velocities is None else hand_velocities.get(h)
                vp = None if part_velocities is None else part_velocities.get(p)
                if vh is not None and vp is not None and np.linalg.norm(vh) >= 2.0 and \
                        np.linalg.norm(np.asarray(vp) - vh) <= 0.5 * np.linalg.norm(vh):
                    st.vel_ok += 1
                else:
                    st.vel_ok = 0
                st.holding = bool(moved or st.vel_ok >= N_VEL)
            if st.touching:
                out[key] = "holding" if st.holding else "touching"
        return out

    def touched_parts(self) -> set[str]:
        """Parts that some hand touches (or holds) now: the connection gate of §14.7 keeps their connections
        pending."""
        return {p for (_, p), st in self._pairs.items() if st.touching}
