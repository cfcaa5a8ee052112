"""The messages the node builds per answer and per marker, constructed without the generated
``__init__``s.

A generated ``__init__`` (rosidl_generator_py) builds a default for every field, e.g. a
``PointStamped()`` makes a ``Header()``, a ``Time()`` and a ``Point()``, which the caller then
overwrites: for one ``TargetCorrection`` that is 27 constructors, about half of the
``~/correct_target`` callback. Here each message is made with ``cls.__new__`` and its slots
(``_<field>``) are written once, exactly what the generated setters store when field checks are
off (the default). With ``ROS_PYTHON_CHECK_FIELDS=1`` (rosidl's switch for type and range
checks) the generated constructors are used instead, so the checks still run.

Every builder takes every field of its message, as values of the field's type (Python floats,
bools, strings and sub-messages): nothing is converted. ``test/ros/test_fast_msgs.py`` checks
that each class has exactly these slots and that the results equal (and serialise to the same
bytes as) messages built the generated way.
"""

from __future__ import annotations

import copy
import sys
from typing import Any

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, PointStamped, Vector3
from std_msgs.msg import Header

from rbc_registration_interfaces.msg import TargetCorrection

#: The message classes built here, and the fields each builder writes (in slot order).
FIELDS = {Point: ("x", "y", "z"), Vector3: ("x", "y", "z"), Header: ("stamp", "frame_id"),
          PointStamped: ("header", "point"),
          TargetCorrection: ("destination", "corrected", "uncorrected", "correction",
                             "correction_applied", "inside_hull", "expected_error", "method",
                             "expected_tre", "tre_bound")}


def _checks_on(cls: type) -> bool:
    """Whether the generated module of ``cls`` checks fields (``ROS_PYTHON_CHECK_FIELDS=1``)."""
    return getattr(sys.modules[cls.__module__], "ros_python_check_fields", "") == "1"


#: False when field checks are on: then the builders call the generated constructors.
FAST = not any(_checks_on(cls) for cls in FIELDS)


def _xyz(cls: type, x: float, y: float, z: float) -> Any:
    if not FAST:
        return cls(x=x, y=y, z=z)
    m = cls.__new__(cls)
    m._check_fields, m._x, m._y, m._z = False, x, y, z
    return m


def point(x: float, y: float, z: float) -> Point:
    """``geometry_msgs/Point(x=x, y=y, z=z)``."""
    return _xyz(Point, x, y, z)


def vector3(x: float, y: float, z: float) -> Vector3:
    """``geometry_msgs/Vector3(x=x, y=y, z=z)``."""
    return _xyz(Vector3, x, y, z)


def point_stamped(stamp: Time, frame_id: str, p: Point) -> PointStamped:
    """``geometry_msgs/PointStamped`` with a new ``Header(stamp=stamp, frame_id=frame_id)``."""
    if not FAST:
        return PointStamped(header=Header(stamp=stamp, frame_id=frame_id), point=p)
    h = Header.__new__(Header)
    h._check_fields, h._stamp, h._frame_id = False, stamp, frame_id
    m = PointStamped.__new__(PointStamped)
    m._check_fields, m._header, m._point = False, h, p
    return m


def target_correction(destination: PointStamped, corrected: PointStamped,
                      uncorrected: PointStamped, correction: Vector3, correction_applied: bool,
                      inside_hull: bool, expected_error: float, method: str,
                      expected_tre: float, tre_bound: float) -> TargetCorrection:
    """``rbc_registration_interfaces/TargetCorrection`` with every field given."""
    if not FAST:
        return TargetCorrection(destination=destination, corrected=corrected,
                                uncorrected=uncorrected, correction=correction,
                                correction_applied=correction_applied, inside_hull=inside_hull,
                                expected_error=expected_error, method=method,
                                expected_tre=expected_tre, tre_bound=tre_bound)
    m = TargetCorrection.__new__(TargetCorrection)
    m._check_fields = False
    m._destination, m._corrected, m._uncorrected = destination, corrected, uncorrected
    m._correction, m._correction_applied = correction, correction_applied
    m._inside_hull, m._expected_error = inside_hull, expected_error
    m._method, m._expected_tre, m._tre_bound = method, expected_tre, tre_bound
    return m


def like(template: Any, **fields: Any) -> Any:
    """A new message of ``template``'s class with ``fields`` (names as in the message) and
    every other field the template's own value: the same objects, shared, not copied, so
    neither message may be changed afterwards. E.g. the correction arrows of ``~/markers``,
    which differ only in ``id`` and ``points`` (about 3 us each instead of 50 us for a generated
    ``Marker()`` and its 9 sub-messages). With field checks on: a deep copy, then the fields set
    the checked way.

    :raises AttributeError: for a name that is not a field of the message.
    """
    cls = type(template)
    slots = cls.__slots__
    for name in fields:
        if "_" + name not in slots:
            raise AttributeError(f"{cls.__name__} has no field {name!r}")
    if _checks_on(cls):
        m = copy.deepcopy(template)
        for name, value in fields.items():
            setattr(m, name, value)
        return m
    m = cls.__new__(cls)
    for slot in slots:
        setattr(m, slot, getattr(template, slot))
    for name, value in fields.items():
        setattr(m, "_" + name, value)
    return m
