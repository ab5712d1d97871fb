"""The closed-form quaternion ↔ matrix conversions of ``tracker.geometry.pose`` give scipy's results bit for bit
(the tracker's figures, e.g. the exact-45° boundary of the assembly relations, must not move when they replace
scipy's slower calls)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tracker.geometry.pose import Pose, matrix_to_quat, normalize_quat, quat_to_matrix


def _quaternions(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4)) * rng.uniform(0.3, 3.0, size=(n, 1))
    q[::5, 1] = 0.0  # some with exact zeros
    q[::7] = [0.0, 0.0, np.sin(np.pi / 8), np.cos(np.pi / 8)]  # exactly 45° about z
    return q


def _matrices(rng: np.random.Generator, n: int) -> np.ndarray:
    R = Rotation.from_quat(rng.normal(size=(n, 4))).as_matrix()
    R[1::4] += rng.normal(size=R[1::4].shape) * 1e-9  # slightly off orthonormal (kept)
    R[2::4] += rng.normal(size=R[2::4].shape) * 1e-3  # clearly off (projected onto a rotation first)
    R[3::4] = Rotation.from_euler("xyz", rng.integers(0, 8, size=(len(R[3::4]), 3)) * 45.0, degrees=True).as_matrix()
    return R


def test_quaternion_to_matrix_matches_scipy_bit_for_bit():
    q = _quaternions(np.random.default_rng(0), 400)
    expected = Rotation.from_quat(q).as_matrix()
    assert np.array_equal(quat_to_matrix(q), expected)
    assert all(np.array_equal(quat_to_matrix(qi), e) for qi, e in zip(q, expected, strict=True))
    assert np.array_equal(quat_to_matrix(q.reshape(20, 20, 4)), expected.reshape(20, 20, 3, 3))


def test_matrix_to_quaternion_matches_scipy_bit_for_bit():
    R = _matrices(np.random.default_rng(1), 400)
    expected = normalize_quat(Rotation.from_matrix(R).as_quat())
    assert np.all(expected[:, 3] >= 0)
    assert np.array_equal(matrix_to_quat(R), expected)
    assert all(np.array_equal(matrix_to_quat(Ri), e) for Ri, e in zip(R, expected, strict=True))
    assert np.array_equal(matrix_to_quat(R.reshape(20, 20, 3, 3)), expected.reshape(20, 20, 4))


def test_single_quaternion_normalisation_matches_the_batch_one():
    q = _quaternions(np.random.default_rng(2), 300) * np.where(np.arange(300) % 2, -1.0, 1.0)[:, None]
    batch = normalize_quat(q)
    assert np.all(batch[:, 3] >= 0)
    assert all(np.array_equal(normalize_quat(qi), b) for qi, b in zip(q, batch, strict=True))


def test_pose_round_trip_and_bad_input():
    rng = np.random.default_rng(3)
    for R in _matrices(rng, 40):
        pose = Pose.from_rt(R, rng.normal(size=3))
        assert np.allclose(pose.R @ pose.R.T, np.eye(3), atol=1e-12)
        assert np.allclose(Pose.from_rt(pose.R, pose.t).q, pose.q, atol=1e-15)
    with pytest.raises(ValueError, match="zero-length"):
        quat_to_matrix(np.zeros(4))
    with pytest.raises(ValueError, match="zero-length"):
        Pose(np.zeros(3), np.zeros(4))
    with pytest.raises(ValueError, match="determinant"):
        matrix_to_quat(-np.eye(3))
    with pytest.raises(ValueError, match="determinant"):
        matrix_to_quat(np.stack([np.eye(3), np.diag([1.0, 1.0, -1.0])]))
    with pytest.raises(ValueError, match="non-finite"):
        Pose(np.array([0.0, np.nan, 0.0]))


def test_single_matrix_kernel_path_equals_the_python_form():
    """One matrix goes through the compiled batch kernel (orthonormal) or the Python form (any other): both give what
    the Python form alone gave, bit for bit, and its error for a left-handed matrix."""
    from tracker.geometry.pose import _matrix_to_quat_one

    R = _matrices(np.random.default_rng(4), 400)
    for Ri in R:
        assert np.array_equal(matrix_to_quat(Ri), normalize_quat(_matrix_to_quat_one(Ri)))
    with pytest.raises(ValueError, match="determinant"):
        matrix_to_quat(np.diag([1.0, -1.0, 1.0]))
    with pytest.raises(ValueError, match="determinant"):
        matrix_to_quat(np.full((3, 3), np.nan))


def test_single_quaternion_product_equals_the_array_form():
    """The plain-float product of one pair equals the array form (``quat_multiply`` on stacked pairs) bit for bit."""
    from tracker.geometry.pose import quat_multiply

    rng = np.random.default_rng(5)
    a, b = _quaternions(rng, 300), _quaternions(rng, 300)[::-1]
    batch = quat_multiply(a, b)
    single = [quat_multiply(ai, bi) for ai, bi in zip(a, b, strict=True)]
    assert all(s.shape == (4,) and s.dtype == np.float64 for s in single)
    assert np.array_equal(np.array(single), batch)
    assert np.array_equal(quat_multiply(list(a[0]), b[0]), batch[0])  # list input as before
