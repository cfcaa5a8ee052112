"""Message <-> numpy conversions (ROS message types, no rclpy.init)."""

import numpy as np
import pytest

pytest.importorskip("rbc_registration_interfaces.msg")

from geometry_msgs.msg import PointStamped  # noqa: E402

from rbc_registration.core.rigid.registration import Registration  # noqa: E402
from rbc_registration.ros import conversions as conv  # noqa: E402


def random_rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    return q if np.linalg.det(q) > 0 else -q


@pytest.mark.parametrize("seed", range(20))
def test_transform_round_trip(seed):
    rng = np.random.default_rng(seed)
    rot = random_rotation(rng)
    if seed == 0:   # 180 degrees about x: trace -1, the branch without a large w
        rot = np.diag([1.0, -1.0, -1.0])
    t = rng.normal(size=3)
    msg = conv.registration_to_transform(Registration(rot, t, 0.0), "world", "tracker",
                                         conv.nanoseconds_to_stamp(1_500_000_000))
    assert (msg.header.frame_id, msg.child_frame_id) == ("world", "tracker")
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1, 500_000_000)
    m = conv.transform_to_matrix(msg)
    np.testing.assert_allclose(m[:3, :3], rot, atol=1e-12)
    np.testing.assert_allclose(m[:3, 3], t, atol=1e-15)
    assert msg.transform.rotation.w >= 0


def test_2d_registration_is_a_rotation_about_z():
    c, s = np.cos(0.3), np.sin(0.3)
    r3, t3 = conv.embed_3d(np.array([[c, -s], [s, c]]), np.array([1.0, 2.0]))
    np.testing.assert_allclose(r3, [[c, -s, 0], [s, c, 0], [0, 0, 1]])
    np.testing.assert_allclose(t3, [1, 2, 0])


def test_targets_frame_check_and_2d_split():
    a, b = PointStamped(), PointStamped()
    a.header.frame_id = "tracker"
    a.point.x, a.point.y, a.point.z = 1.0, 2.0, 3.0
    b.point.z = 7.0  # empty frame: the working frame
    points, z = conv.targets_to_array([a, b], "tracker", 2)
    np.testing.assert_array_equal(points, [[1, 2], [0, 0]])
    np.testing.assert_array_equal(z, [3, 7])
    b.header.frame_id = "camera"
    with pytest.raises(ValueError, match="target 1 has frame_id 'camera'"):
        conv.targets_to_array([a, b], "tracker", 3)


def test_stamps():
    t = conv.nanoseconds_to_stamp(12_000_000_345)
    assert conv.stamp_to_seconds(t) == pytest.approx(12.000000345)


def test_every_sigma_source_of_the_core_has_a_status_value():
    from rbc_registration.core.constants import SIGMA_SOURCES
    from rbc_registration.ros.status import STATUS_SIGMA_SOURCE

    assert set(STATUS_SIGMA_SOURCE) == set(SIGMA_SOURCES)
    assert STATUS_SIGMA_SOURCE["given"] == "parameter"


def test_a_2d_target_with_a_nan_z_is_named_without_a_numpy_repr():
    msgs = [PointStamped(), PointStamped()]
    msgs[1].point.z = float("nan")
    with pytest.raises(ValueError, match=r"^target 1 has z = nan: coordinates must be finite"):
        conv.targets_to_array(msgs, "tracker", 2)
