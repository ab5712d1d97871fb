"""Geometry of the simulated hand: a palm (box), four fingers and a thumb (capsules) and a forearm (capsule).

Hand frame (metres): origin at the centre of the grasped object, y up (table normal), z towards the user
(the forearm's side), x to the hand's side. The hand grasps from above: the palm hovers over the object,
the fingers reach down along the object's far face (−z), the thumb along its near face (+z), and the
forearm rises towards the user, so the hand enters the image from its bottom edge.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SKIN_PALM = (226.0, 176.0, 146.0)
SKIN_FINGER = (218.0, 164.0, 134.0)
SKIN_ARM = (208.0, 152.0, 122.0)


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
) -> list[Capsule | Box]:
    """Primitives of the hand in the parent frame of the hand pose ``(pose_R, pose_t)``.

    ``grip`` 0 = open, 1 = closed on the object whose half extents along y (``half_height``) and along z
    (``half_depth``) are given; ``scale`` widens palm, fingers and forearm (the occlusion option).
    """
    s = float(scale)
    opening = (1.0 - float(np.clip(grip, 0.0, 1.0))) * 0.022
    top = half_height + 0.014  # palm bottom above the object's top
    prims_local: list[Capsule | Box] = []
    palm_half = np.array([0.040 * s, 0.012, 0.045])
    palm_c = np.array([0.0, top + palm_half[1], 0.012])
    prims_local.append(Box(np.eye(3), palm_c, palm_half, SKIN_PALM))
    # fingers along the far face
    r_f = 0.0085 * min(s, 1.4)
    xs = np.linspace(-0.027, 0.027, 4) * s
    lengths = (0.055, 0.062, 0.060, 0.050)
    for x, ln in zip(xs, lengths, strict=True):
        base = np.array([x, top + 0.008, palm_c[2] - palm_half[2] + 0.004])
        tip_z = -(half_depth + r_f + 0.001) - opening
        tip = np.array([x * 0.85, max(-half_height * 0.4, top + 0.008 - ln), tip_z])
        knuckle = np.array([x, top + 0.004, tip_z * 0.9])
        prims_local.append(Capsule(base, knuckle, r_f, SKIN_FINGER))
        prims_local.append(Capsule(knuckle, tip, r_f * 0.92, SKIN_FINGER))
    # thumb on the near face
    r_t = 0.0105 * min(s, 1.4)
    t_base = np.array([-0.02 * s, top + 0.006, palm_c[2] + 0.02])
    t_tip = np.array([-0.005 * s, -half_height * 0.2, half_depth + r_t + 0.001 + opening])
    prims_local.append(Capsule(t_base, t_tip, r_t, SKIN_FINGER))
    # wrist and forearm rising towards the user
    wrist = np.array([0.0, top + 0.016, palm_c[2] + palm_half[2] + 0.01])
    direction = np.array([0.0, np.sin(np.radians(14.0)), np.cos(np.radians(14.0))])
    elbow = wrist + 0.42 * direction
    prims_local.append(Capsule(wrist - 0.02 * direction, wrist + 0.02 * direction, 0.026 * s, SKIN_ARM))
    prims_local.append(Capsule(wrist + 0.02 * direction, elbow, 0.033 * s, SKIN_ARM))

    out: list[Capsule | Box] = []
    for p in prims_local:
        if isinstance(p, Capsule):
            out.append(Capsule(pose_R @ p.a + pose_t, pose_R @ p.b + pose_t, p.radius, p.albedo))
        else:
            out.append(Box(pose_R @ p.R, pose_R @ p.t + pose_t, p.half, p.albedo))
    return out
