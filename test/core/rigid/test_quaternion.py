"""rpy_from_matrix: roll, pitch, yaw of REP 103 (fixed axes X, Y, Z, as tf2's getRPY and URDF's
``<origin rpy>``), checked against tf2's closed form and by rebuilding the matrix."""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbc_registration.core.rigid.quaternion import quaternion_from_matrix, rpy_from_matrix


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _fixed_xyz(roll, pitch, yaw):
    """R of roll about X, then pitch about the fixed Y, then yaw about the fixed Z."""
    return _rz(yaw) @ _ry(pitch) @ _rx(roll)


def _tf2_get_rpy(r):
    """tf2's Matrix3x3::getEulerYPR away from gimbal lock (solution 1)."""
    pitch = -math.asin(r[2, 0])
    c = math.cos(pitch)
    return (math.atan2(r[2, 1] / c, r[2, 2] / c), pitch, math.atan2(r[1, 0] / c, r[0, 0] / c))


@pytest.mark.parametrize("seed", range(20))
def test_random_rotations_give_tf2s_angles_and_rebuild_the_matrix(seed):
    r = Rotation.random(random_state=seed).as_matrix()
    rpy = rpy_from_matrix(r)
    np.testing.assert_allclose(rpy, _tf2_get_rpy(r), atol=1e-12)
    np.testing.assert_allclose(_fixed_xyz(*rpy), r, atol=1e-12)
    roll, pitch, yaw = rpy
    assert -math.pi <= roll <= math.pi and -math.pi / 2 <= pitch <= math.pi / 2
    assert -math.pi <= yaw <= math.pi


@pytest.mark.parametrize("rpy", [(0.1, 0.0, 0.0), (0.0, -0.7, 0.0), (0.0, 0.0, 2.5),
                                 (0.3, -0.2, -3.0), (-2.9, 1.2, 0.4)])
def test_known_angles_come_back(rpy):
    np.testing.assert_allclose(rpy_from_matrix(_fixed_xyz(*rpy)), rpy, atol=1e-12)


def test_a_quarter_turn_about_z_is_a_yaw_of_90_degrees_and_matches_its_quaternion():
    r = _rz(math.pi / 2)
    assert np.degrees(rpy_from_matrix(r)) == pytest.approx((0.0, 0.0, 90.0), abs=1e-12)
    x, y, z, w = quaternion_from_matrix(r)
    assert (x, y) == (0.0, 0.0) and 2 * math.atan2(z, w) == pytest.approx(math.pi / 2)


@pytest.mark.parametrize("pitch", [math.pi / 2, -math.pi / 2])
@pytest.mark.parametrize("rest", [0.0, 0.8, -2.0])
def test_gimbal_lock_still_rebuilds_the_matrix(pitch, rest):
    r = _fixed_xyz(rest, pitch, 0.4)
    roll, got_pitch, yaw = rpy_from_matrix(r)
    assert got_pitch == pytest.approx(pitch, abs=1e-7) and roll == 0.0
    np.testing.assert_allclose(_fixed_xyz(roll, got_pitch, yaw), r, atol=1e-7)


@pytest.mark.parametrize("angle", [0.0, 0.3, -1.9, math.pi])
def test_a_2d_rotation_is_a_yaw(angle):
    c, s = math.cos(angle), math.sin(angle)
    roll, pitch, yaw = rpy_from_matrix([[c, -s], [s, c]])
    assert (roll, pitch) == (0.0, 0.0)
    assert math.cos(yaw) == pytest.approx(c, abs=1e-15) and math.sin(yaw) == pytest.approx(s,
                                                                                           abs=1e-15)


def test_no_negative_zero():
    assert all(math.copysign(1.0, a) > 0 for a in rpy_from_matrix(np.eye(3)))
    assert all(math.copysign(1.0, a) > 0 for a in rpy_from_matrix(np.eye(2)))


@pytest.mark.parametrize("bad", [np.eye(4), np.diag([1.0, 1.0, -1.0]), 2 * np.eye(3),
                                 [[np.nan, 0], [0, 1]]])
def test_not_a_rotation_is_refused(bad):
    with pytest.raises(ValueError, match="rotation"):
        rpy_from_matrix(bad)
