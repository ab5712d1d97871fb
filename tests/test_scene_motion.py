"""Scene motion (filter/scene_motion.py): hidden parts follow the camera motion the visible resting parts agree on."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from tracker.filter.scene_motion import consensus_motion


def _landmark(Rd: np.ndarray, td: np.ndarray, c: np.ndarray, noise: np.random.Generator | None = None):
    """A landmark at centre ``c`` moved by ``(Rd, td)`` (plus a little refinement noise)."""
    if noise is not None:
        Rd = Rotation.from_rotvec(noise.normal(0, 2e-4, 3)).as_matrix() @ Rd
        td = td + noise.normal(0, 2e-4, 3)
    return Rd, td, c


def test_the_motion_most_landmarks_agree_on_wins_over_a_part_pushed_by_a_hand():
    rng = np.random.default_rng(3)
    Rd = Rotation.from_euler("xyz", [0.4, -0.3, 0.2], degrees=True).as_matrix()
    td = np.array([0.004, -0.002, 0.003])
    centres = rng.uniform([-0.15, -0.1, 0.55], [0.15, 0.1, 0.75], (4, 3))
    pairs = [_landmark(Rd, td, c, rng) for c in centres]
    pushed = Rotation.from_euler("z", 5.0, degrees=True).as_matrix()
    pairs.append((pushed, np.array([0.02, 0.0, 0.0]), np.array([0.0, 0.0, 0.6])))  # moved by a hand
    R, t = consensus_motion(pairs, tolerance=0.003, min_agree=2)
    probe = np.array([0.05, 0.05, 0.65])  # a hidden part's centre
    assert np.linalg.norm((R @ probe + t) - (Rd @ probe + td)) < 0.001
    assert np.degrees(np.arccos(np.clip((np.trace(R.T @ Rd) - 1) / 2, -1, 1))) < 0.1


def test_no_motion_without_enough_agreeing_landmarks():
    rng = np.random.default_rng(4)
    a = _landmark(np.eye(3), np.array([0.01, 0.0, 0.0]), np.array([0.0, 0.0, 0.6]))
    b = _landmark(np.eye(3), np.array([-0.01, 0.0, 0.0]), np.array([0.1, 0.0, 0.6]))
    assert consensus_motion([a], 0.003, 2) is None  # one landmark alone
    assert consensus_motion([a, b], 0.003, 2) is None  # two that disagree
    c = _landmark(np.eye(3), np.array([0.01, 0.0, 0.0]), np.array([-0.1, 0.05, 0.7]), rng)
    d = _landmark(np.eye(3), np.array([-0.01, 0.0, 0.0]), np.array([0.1, 0.05, 0.7]), rng)
    assert consensus_motion([a, b, c, d], 0.003, 2) is None  # a tie is no majority
    R, t = consensus_motion([a, b, c], 0.003, 2)
    assert np.allclose(R, np.eye(3), atol=1e-3) and np.linalg.norm(t - [0.01, 0.0, 0.0]) < 0.001
