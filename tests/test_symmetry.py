import numpy as np
from scipy.spatial.transform import Rotation

from tracker.geometry.parts import PartSpec
from tracker.geometry.symmetry import box_group, cube_group, nearest_in_group, symmetric_rotation_error


def test_cube_group_is_a_group_of_24_distinct_rotations():
    g = cube_group()
    assert g.shape == (24, 3, 3)
    assert np.allclose(g[0], np.eye(3))
    flat = {tuple(m.astype(int).ravel()) for m in g}
    assert len(flat) == 24
    # closed under multiplication
    for a in g[:6]:
        for b in g:
            assert tuple((a @ b).astype(int).ravel()) in flat


def test_box_group_sizes():
    assert len(box_group((0.036, 0.036, 0.036))) == 24
    assert len(box_group((0.02, 0.02, 0.10))) == 8
    assert len(box_group((0.01, 0.02, 0.03))) == 4


def test_symmetric_error_ignores_cube_symmetry_but_not_real_rotation():
    cube = PartSpec.cube("c")
    g = box_group(cube.box)
    R = Rotation.from_euler("xyz", [0.3, -0.2, 0.9]).as_matrix()
    for S in g:
        assert symmetric_rotation_error(R @ S, R, g) < 1e-6
    Rz = Rotation.from_euler("z", 10, degrees=True).as_matrix()
    err = symmetric_rotation_error(R @ Rz, R, g)
    assert np.isclose(np.degrees(err), 10.0, atol=1e-6)
    # a 45-degree turn is the farthest a cube can be from a symmetric copy about one axis
    R45 = Rotation.from_euler("z", 45, degrees=True).as_matrix()
    assert np.isclose(np.degrees(symmetric_rotation_error(R45, np.eye(3), g)), 45.0, atol=1e-6)


def test_nearest_in_group():
    S = cube_group()[7]
    noisy = S @ Rotation.from_rotvec([0.05, -0.03, 0.02]).as_matrix()
    i, M = nearest_in_group(noisy)
    assert i == 7 and np.allclose(M, S)
