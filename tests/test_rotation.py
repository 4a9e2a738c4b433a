"""pipeline.rotation against known rotations and MuJoCo's own quaternion routines."""

import mujoco
import numpy as np
import pytest

from pipeline import rotation as rot


def _unit(rng, n):
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_quarter_turn_about_z_maps_x_to_y():
    q = rot.yaw_quat(np.pi / 2)
    np.testing.assert_allclose(q, [np.sqrt(0.5), 0, 0, np.sqrt(0.5)], atol=1e-15)
    np.testing.assert_allclose(rot.quat_to_mat(q) @ [1.0, 0, 0], [0, 1.0, 0], atol=1e-15)


def test_product_and_matrix_match_mujoco():
    rng = np.random.default_rng(0)
    a, b = _unit(rng, 20), _unit(rng, 20)
    prod = rot.quat_mul(a, b)
    mats = rot.quat_to_mat(a)
    for i in range(20):
        ref = np.zeros(4)
        mujoco.mju_mulQuat(ref, a[i], b[i])
        np.testing.assert_allclose(prod[i], ref, atol=1e-14)
        m = np.zeros(9)
        mujoco.mju_quat2Mat(m, a[i])
        np.testing.assert_allclose(mats[i], m.reshape(3, 3), atol=1e-14)


def test_rotvec_round_trip_and_shortest_arc():
    rng = np.random.default_rng(1)
    r = rng.uniform(-1, 1, size=(50, 3))  # |r| < pi
    np.testing.assert_allclose(rot.quat_to_rotvec(rot.rotvec_to_quat(r)), r, atol=1e-13)
    q = rot.rotvec_to_quat(r)
    np.testing.assert_allclose(rot.quat_to_rotvec(-q), r, atol=1e-13)  # -q is the same rotation
    assert rot.quat_to_rotvec(np.ones((2, 3, 4))).shape == (2, 3, 3)


def test_angle_between_orientations():
    q1 = rot.yaw_quat(0.2)
    q2 = rot.quat_mul(rot.axis_angle_quat((1.0, 1.0, 0.0), 0.7), q1)
    assert rot.quat_angle(q1, q2) == pytest.approx(0.7, abs=1e-12)
    assert rot.quat_angle(q2, -q2) == pytest.approx(0.0, abs=1e-12)


def test_bad_shapes_and_axes_raise():
    with pytest.raises(ValueError, match=r"\(\.\.\., 4\)"):
        rot.quat_to_mat([1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="axis"):
        rot.axis_angle_quat((0.0, 0.0, 0.0), 1.0)
