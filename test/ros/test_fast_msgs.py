"""The fast message builders (ros/fast_msgs.py) give exactly the messages the generated
constructors give: same slots, equal fields, the same serialised bytes (no rclpy.init)."""

import numpy as np
import pytest

pytest.importorskip("rbc_registration_interfaces.msg")

from builtin_interfaces.msg import Time  # noqa: E402
from geometry_msgs.msg import Point, PointStamped, Vector3  # noqa: E402
from rclpy.serialization import serialize_message  # noqa: E402

from rbc_registration_interfaces.msg import TargetCorrection  # noqa: E402
from rbc_registration.core.model import TargetCorrections  # noqa: E402
from rbc_registration.ros import conversions as conv  # noqa: E402
from rbc_registration.ros import fast_msgs  # noqa: E402


def slow_target_corrections_to_msgs(tc, z, method, destination_frame, stamps):
    """The conversion as it was before fast_msgs (generated constructors, then overwritten)."""
    applied = method != "uncorrected"
    corrected = conv._to_xyz(np.asarray(tc.corrected), z)
    uncorrected = conv._to_xyz(np.asarray(tc.uncorrected), z)
    destination = conv._to_xyz(np.asarray(tc.destination), z)
    correction = conv._to_xyz(np.asarray(tc.correction), np.zeros_like(z))
    inside = np.asarray(tc.inside_hull, dtype=bool)
    expected = np.asarray(tc.expected_error, dtype=np.float64)
    out = []
    for k in range(len(z)):
        c = PointStamped(point=Point(x=float(corrected[k][0]), y=float(corrected[k][1]),
                                     z=float(corrected[k][2])))
        u = PointStamped(point=Point(x=float(uncorrected[k][0]), y=float(uncorrected[k][1]),
                                     z=float(uncorrected[k][2])))
        d = PointStamped(point=Point(x=float(destination[k][0]), y=float(destination[k][1]),
                                     z=float(destination[k][2])))
        for point in (c, u, d):
            point.header.frame_id = destination_frame
            point.header.stamp = stamps[k]
        out.append(TargetCorrection(
            destination=d if applied else u, corrected=c, uncorrected=u,
            correction=Vector3(x=float(correction[k][0]), y=float(correction[k][1]),
                               z=float(correction[k][2])),
            correction_applied=bool(applied), inside_hull=bool(inside[k]),
            expected_error=float(expected[k]), method=method,
            expected_tre=float(tc.expected_tre[k]), tre_bound=float(tc.tre_bound[k])))
    return out


@pytest.mark.parametrize("cls", list(fast_msgs.FIELDS))
def test_builders_write_every_slot(cls):
    """A generated class with other slots than the builder writes fails here, not silently."""
    fields = fast_msgs.FIELDS[cls]
    assert tuple(cls.get_fields_and_field_types()) == fields
    assert sorted(cls.__slots__) == sorted(["_check_fields", *("_" + f for f in fields)])


def random_corrections(rng, k, d, kriging, method):
    corrected, uncorrected = rng.normal(size=(k, d)), rng.normal(size=(k, d))
    destination = uncorrected if method == "uncorrected" else (
        corrected if method == "paper" else rng.normal(size=(k, d)))
    return TargetCorrections(
        corrected=corrected, uncorrected=uncorrected,
        correction=rng.normal(scale=1e-3, size=(k, d)), inside_hull=rng.random(k) < 0.5,
        expected_error=rng.random(k) if kriging else np.full(k, np.nan),
        destination=destination, expected_tre=rng.random(k),
        tre_bound=rng.random(k) if k > 1 else np.full(k, np.nan))


@pytest.mark.parametrize("seed", range(6))
def test_target_corrections_equal_the_generated_way(seed):
    rng = np.random.default_rng(seed)
    d, k = (2, 3)[seed % 2], (1, 7, 40)[seed % 3]
    method = ("uncorrected", "paper", "kriging")[seed % 3]
    applied = method != "uncorrected"
    tc = random_corrections(rng, k, d, kriging=seed % 3 == 0, method=method)
    z = rng.normal(size=k)
    stamps = [Time(sec=int(s), nanosec=int(n)) for s, n in zip(rng.integers(0, 2**31, k),
                                                             rng.integers(0, 10**9, k))]
    frame = ("world", "robot/base_link", "wörld")[seed % 3]
    fast = conv.target_corrections_to_msgs(tc, z, method, frame, stamps)
    slow = slow_target_corrections_to_msgs(tc, z, method, frame, stamps)
    assert len(fast) == len(slow) == k
    for f, s in zip(fast, slow):
        for name in fast_msgs.FIELDS[TargetCorrection]:
            a, b = getattr(f, name), getattr(s, name)
            assert type(a) is type(b), name
            if name not in ("expected_error", "tre_bound"):
                assert a == b, name
            else:
                assert a == b or (np.isnan(a) and np.isnan(b)), name
        assert (f.destination is f.uncorrected) == (s.destination is s.uncorrected) != applied
        assert serialize_message(f) == serialize_message(s)
        assert repr(f) == repr(s)


def test_points_and_vectors():
    for x, y, z in ((0.0, -0.0, 1e-300), (1.5, float("inf"), -2.25)):
        assert fast_msgs.point(x, y, z) == Point(x=x, y=y, z=z)
        assert fast_msgs.vector3(x, y, z) == Vector3(x=x, y=y, z=z)
        assert serialize_message(fast_msgs.point(x, y, z)) == serialize_message(
            Point(x=x, y=y, z=z))
    assert conv.array_to_point(np.array([1, 2, 3])) == Point(x=1.0, y=2.0, z=3.0)
    assert type(conv.array_to_vector3(np.array([1.0, 2, 3])).x) is float


def test_fields_can_be_set_afterwards():
    """A fast message behaves as a generated one: fields can be changed and read."""
    ps = fast_msgs.point_stamped(Time(sec=3), "world", fast_msgs.point(1.0, 2.0, 3.0))
    ps.header.frame_id = "map"
    ps.point.x = 9.0
    expected = PointStamped()
    expected.header.frame_id, expected.header.stamp = "map", Time(sec=3)
    expected.point.x, expected.point.y, expected.point.z = 9.0, 2.0, 3.0
    assert ps == expected


def test_like_is_the_template_with_the_fields_given():
    """``like``: equal to a generated message with the same fields, the same bytes, every slot
    written, the template unchanged; an unknown field is refused."""
    from visualization_msgs.msg import Marker
    template = Marker(type=Marker.ARROW, ns="rbc/corrections", action=Marker.ADD)
    template.header.frame_id, template.header.stamp = "world", Time(sec=7, nanosec=5)
    template.scale.x, template.color.r, template.pose.orientation.w = 0.2, 0.9, 1.0
    points = [fast_msgs.point(1.0, 2.0, 3.0), fast_msgs.point(4.0, 5.0, 6.0)]
    got = fast_msgs.like(template, id=42, points=points)
    expected = Marker(type=Marker.ARROW, ns="rbc/corrections", action=Marker.ADD, id=42,
                      points=[Point(x=1.0, y=2.0, z=3.0), Point(x=4.0, y=5.0, z=6.0)])
    expected.header.frame_id, expected.header.stamp = "world", Time(sec=7, nanosec=5)
    expected.scale.x, expected.color.r, expected.pose.orientation.w = 0.2, 0.9, 1.0
    assert type(got) is Marker and got == expected
    assert serialize_message(got) == serialize_message(expected)
    assert all(hasattr(got, slot) for slot in Marker.__slots__)
    assert template.id == 0 and template.points == []
    with pytest.raises(AttributeError, match="no field 'colour'"):
        fast_msgs.like(template, colour=None)
