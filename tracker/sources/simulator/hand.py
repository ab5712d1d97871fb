"""Geometry of the simulated hand: a palm (box), four fingers and a thumb (capsules) and a forearm (capsule).

Hand frame (metres): origin at the centre of the grasped object, y up (table normal), z towards the user
(the forearm's side), x to the hand's side. The hand grasps from above: the palm (three rounded segments)
lies just behind the object, the fingers reach forward over its top and down its far face (−z), the thumb
comes down on its near face (+z), and the forearm rises towards the user, so the hand enters the image
from its bottom edge.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SKIN_PALM = (226.0, 176.0, 146.0)
SKIN_FINGER = (218.0, 164.0, 134.0)
SKIN_ARM = (208.0, 152.0, 122.0)
N_ARM_PRIMS = 3
"""The last primitives of :func:`hand_primitives` that make up the arm (forearm in two pieces, upper arm)."""


@dataclass(frozen=True)
class Capsule:
    """Segment ``a``–``b`` swept by a sphere of ``radius`` (metres), RGB ``albedo`` 0..255."""

    a: np.ndarray
    b: np.ndarray
    radius: float
    albedo: tuple[float, float, float]


@dataclass(frozen=True)
class Box:
    """Box with centre ``t``, rotation ``R`` (body → parent), half extents ``half`` (metres), RGB ``albedo``."""

    R: np.ndarray
    t: np.ndarray
    half: np.ndarray
    albedo: tuple[float, float, float]


def hand_primitives(
    pose_R: np.ndarray,
    pose_t: np.ndarray,
    grip: float,
    half_height: float = 0.018,
    half_depth: float = 0.018,
    scale: float = 1.0,
    shoulder: np.ndarray | None = None,
    mirror: bool = False,
    albedos: tuple[tuple[float, float, float], ...] | None = None,
    wrist_taper: float = 0.8,
) -> list[Capsule | Box]:
    """Primitives of the hand in the parent frame of the hand pose ``(pose_R, pose_t)``.

    ``grip`` 0 = open, 1 = closed on the object whose half extents along y (``half_height``) and along z
    (``half_depth``) are given; ``scale`` widens palm, fingers and forearm (the occlusion option);
    ``shoulder`` (parent frame) is where the arm goes: the forearm (0.28 m) points from the wrist towards it
    and the upper arm joins the elbow to it; ``mirror`` makes a left hand (x → −x); ``albedos`` = RGB of (palm,
    fingers, arm) (default the built-in skin colours; a sleeve colour for the arm gives long sleeves). The last
    :data:`N_ARM_PRIMS` primitives are the arm (forearm from the wrist, upper arm), the others palm and fingers;
    ``wrist_taper`` scales the palm segments' lateral offset at the wrist end (0.8 by default; the hand-tracking
    scenarios use 0.4 so that the palm stays within the forearm's width there and no palm sliver shows beside a
    sleeve).
    """
    palm_rgb, finger_rgb, arm_rgb = albedos if albedos is not None else (SKIN_PALM, SKIN_FINGER, SKIN_ARM)
    s = float(scale)
    opening = (1.0 - float(np.clip(grip, 0.0, 1.0))) * 0.022
    top = half_height + 0.012  # height of the palm's underside above the object's centre
    prims_local: list[Capsule | Box] = []
    # palm: three parallel rounded segments from the knuckles (z ≈ 0) back towards the wrist
    r_p = 0.0145 * s
    y_p = top + r_p
    for x in (-0.024 * s, 0.0, 0.024 * s):
        wrist_end = np.array([x * wrist_taper, y_p + 0.004, 0.068])
        prims_local.append(Capsule(np.array([x, y_p, 0.004]), wrist_end, r_p, palm_rgb))
    # four fingers: from the knuckles forward over the object's top, then down its far face (−z)
    r_f = 0.0085 * min(s, 1.4)
    lengths = (0.030, 0.034, 0.032, 0.026)
    for x, ln in zip(np.linspace(-0.027, 0.027, 4) * s, lengths, strict=True):
        knuckle = np.array([x, y_p, 0.0])
        tip_z = -(half_depth + r_f + 0.001) - opening
        middle = np.array([x, y_p - 0.004, min(tip_z + 0.004, -ln * 0.6)])
        tip = np.array([x * 0.9, y_p - 0.004 - ln, tip_z])
        prims_local.append(Capsule(knuckle, middle, r_f, finger_rgb))
        prims_local.append(Capsule(middle, tip, r_f * 0.9, finger_rgb))
    # thumb from the side of the palm down to the near face (+z)
    r_t = 0.0105 * min(s, 1.4)
    t_base = np.array([-0.036 * s, y_p - 0.004, 0.05])
    t_mid = np.array([-0.022 * s, top - 0.004, half_depth + r_t + 0.012 + opening])
    t_tip = np.array([-0.006 * s, -half_height * 0.25, half_depth + r_t + 0.001 + opening])
    prims_local.append(Capsule(t_base, t_mid, r_t, finger_rgb))
    prims_local.append(Capsule(t_mid, t_tip, r_t * 0.92, finger_rgb))
    wrist = np.array([0.0, y_p + 0.006, 0.075])
    wrist_in = np.array([0.0, y_p + 0.004, 0.055])

    if mirror:
        flip = np.diag([-1.0, 1.0, 1.0])
        prims_local = [Capsule(flip @ p.a, flip @ p.b, p.radius, p.albedo) for p in prims_local]
    out: list[Capsule | Box] = []
    for p in prims_local:
        if isinstance(p, Capsule):
            out.append(Capsule(pose_R @ p.a + pose_t, pose_R @ p.b + pose_t, p.radius, p.albedo))
        else:
            out.append(Box(pose_R @ p.R, pose_R @ p.t + pose_t, p.half, p.albedo))
    # forearm and upper arm in the parent frame, towards the shoulder
    w = pose_R @ wrist + pose_t
    w_in = pose_R @ wrist_in + pose_t
    if shoulder is None:
        shoulder = w + pose_R @ np.array([0.0, 0.25, 0.6])
    to_sh = np.asarray(shoulder, float) - w
    dist = float(np.linalg.norm(to_sh))
    elbow = w + to_sh * min(0.28 / max(dist, 1e-6), 0.6)
    out.append(Capsule(w_in, w + 0.4 * (elbow - w), 0.027 * s, arm_rgb))
    out.append(Capsule(w + 0.4 * (elbow - w), elbow, 0.031 * s, arm_rgb))
    out.append(Capsule(elbow, np.asarray(shoulder, float), 0.034 * s, arm_rgb))
    return out
