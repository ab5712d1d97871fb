"""Constant-velocity motion model with adaptive noise (tracker/filter/predict.py): velocity estimated from the
final estimates, carried on by the prediction, noise widened with speed; the seed's model is left as it was."""

from __future__ import annotations

import numpy as np
import pytest

from tracker.filter import predict
from tracker.filter.particle_filter import MultiObjectTracker
from tracker.filter.tracker_config import TrackerConfig
from tracker.geometry.camera import Intrinsics
from tracker.geometry.parts import PartSpec
from tracker.geometry.pose import Pose


def _tracker(model: str) -> MultiObjectTracker:
    cfg = TrackerConfig.preset("default").with_overrides(n_particles=40, velocity_model=model)
    tr = MultiObjectTracker([PartSpec.cube("red", "red"), PartSpec.cube("blue", "blue")], Intrinsics.default(160, 120),
                            cfg, seed=0)
    tr.initialize({"red": Pose([0, 0, 0.6], [0, 0, 0, 1]), "blue": Pose([0.1, 0, 0.6], [0, 0, 0, 1])})
    return tr


def test_constant_velocity_is_estimated_carried_on_and_widens_the_noise():
    tr = _tracker("constant")
    step = np.array([0.004, -0.002, 0.0])
    seen = np.array([True, False])  # blue is not supported by the data: no velocity
    for k in range(6):
        poses = {"red": Pose(np.array([0, 0, 0.6]) + k * step, [0, 0, 0, 1]),
                 "blue": Pose(np.array([0.1, 0, 0.6]) + k * step, [0, 0, 0, 1])}
        predict.update_velocities(tr, poses, seen)
    assert np.allclose(tr._est_vel[0, :3], step, atol=0.0003)  # smoothed mean of a steady 4.5 mm per frame
    assert np.allclose(tr._est_vel[1], 0.0)
    scale = predict.adaptive_noise(tr)
    cfg = tr.config
    assert scale[0] == pytest.approx(min(1 + cfg.cv_noise_gain * np.linalg.norm(tr._est_vel[0, :3]) / cfg.sigma_v,
                                         cfg.cv_noise_max))
    assert scale[0] > 1.5 and scale[1] == 1.0
    p0 = tr.p.copy()
    p_pred, _, _ = predict.deterministic(tr, np.zeros((2, 3)))
    shift = (p_pred - p0).mean(axis=0)
    assert np.allclose(shift[0], cfg.cv_gain * tr._est_vel[0, :3], atol=1e-9)  # carried on with gain cv_gain
    assert np.allclose(shift[1], 0.0)


def test_the_seed_model_keeps_its_particle_velocities():
    tr = _tracker("seed")
    tr.v[:, 0, :3] = 0.01
    predict.update_velocities(tr, dict(tr.estimates), np.array([True, True]))
    assert np.allclose(tr.v[:, 0, :3], 0.01)  # untouched
    assert np.allclose(predict.adaptive_noise(tr), 1.0)
    p_pred, _, _ = predict.deterministic(tr, np.zeros((2, 3)))
    assert np.allclose(p_pred[:, 0] - tr.p[:, 0], tr.config.k_v * 0.01)
