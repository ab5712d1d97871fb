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

import cv2
import numpy as np

from tracker.odometry.exclusion_mask import PART_MARGIN_PX


class HandExclusion:
    """Call with each frame's RGB image (uint8 H×W×3), in order: returns the H×W bool mask of the hands seen in it
    (True = exclude), or None while no hand is tracked. One instance per recording (the hand tracker keeps tracks
    from frame to frame)."""

    def __init__(self, focal: float | None = None, margin: int = PART_MARGIN_PX, seed: int = 0) -> None:
        from tracker.hands.tracker import HandTracker, HandTrackerConfig

        self.tracker = HandTracker(HandTrackerConfig(seed=seed), focal=focal)
        self.margin = int(margin)
        self._kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * self.margin + 1, 2 * self.margin + 1))

    def __call__(self, rgb: np.ndarray) -> np.ndarray | None:
        hands = self.tracker.process(rgb)
        if not hands:
            return None
        h, w = rgb.shape[:2]
        m = np.zeros((h, w), np.uint8)
        for hm in self.tracker.hand_masks().values():
            m |= hm.view(np.uint8)
        arm = self.tracker.arm_mask()
        if arm is not None:
            m |= arm.view(np.uint8)
        for hand in hands:
            u0, v0, u1, v1 = hand.box
            m[max(v0, 0):max(v1, 0), max(u0, 0):max(u1, 0)] = 1
        if self.margin > 0:
            m = cv2.dilate(m, self._kernel)
        return m.astype(bool)
