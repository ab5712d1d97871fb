"""Hands found in the colour image as an exclusion mask for the camera odometry, for recordings without ground-truth
hand boxes (a real camera).

A hand that moves parts in front of a moving camera is the largest thing in the scene that does not move with it:
with no mask the dense odometry registers part of the hand's motion (tuning sessions, hand-held camera, a hand
moving parts, levels 160×120 to 640×480: ATE 178 / 92 / 3.6 mm with no mask against 2.4 / 0.8 / 0.2 mm with the
simulator's hand box). The hand tracker of :mod:`tracker.hands` (skin colour against the session's background,
optical-flow motion clusters, automatic start of tracks) finds the hands from the images alone; its hand masks, the
skin components that reach into a hand's box (a bare forearm) and the hands' boxes, dilated by ``margin`` pixels,
are what this module excludes: ATE 2.7 / 0.5 / 2.0 mm on the same sessions, and a static scene without a hand is
unchanged (no track starts). Pixels: full-resolution colour-image pixels; True = exclude.
"""

from __future__ import annotations

import numpy as np

from tracker.geometry.camera import Intrinsics
from tracker.odometry.exclusion_mask import PART_MARGIN_PX


class HandExclusion:
    """Call with each frame's RGB image (uint8 H×W×3), in order: returns the H×W bool mask of the hands seen in it
    (True = exclude), or None while no hand is tracked. One instance per recording (the hand tracker keeps tracks
    from frame to frame). The hand and forearm pixels are the hand loop's occluder mask H_k
    (:meth:`tracker.hands.loop.HandLoop.occluder_mask`, dilated by ``margin``), the boxes are added grown by it."""

    def __init__(self, intrinsics: Intrinsics, margin: int = PART_MARGIN_PX, seed: int = 0) -> None:
        from tracker.hands.loop import HandLoop, HandLoopConfig
        from tracker.hands.tracker import HandTrackerConfig

        self.margin = int(margin)
        self.loop = HandLoop([], intrinsics, HandLoopConfig(tracker=HandTrackerConfig(seed=seed), overlap="off",
                                                            occluder_radius_px=self.margin))

    def __call__(self, rgb: np.ndarray) -> np.ndarray | None:
        hands = self.loop.perceive(rgb, None, None, {})
        if not hands:
            return None
        h, w = rgb.shape[:2]
        m = self.loop.occluder_mask()
        if m is None:
            m = np.zeros((h, w), bool)
        g = self.margin
        for hand in hands:
            u0, v0, u1, v1 = hand.box
            m[max(v0 - g, 0):max(v1 + g, 0), max(u0 - g, 0):max(u1 + g, 0)] = True
        return m
