"""A calibration as URDF / xacro: a fixed ``<joint>`` whose ``<origin xyz="..." rpy="..."/>`` is
the pose of the child (working) frame in the parent (destination) frame, metres and radians.

URDF's ``rpy`` is roll, pitch, yaw about the fixed axes X, Y, Z (``R = Rz(yaw) Ry(pitch)
Rx(roll)``, REP 103, tf2's ``getRPY``):
:func:`~rbc_registration.core.rigid.quaternion.rpy_from_matrix`.
The file :func:`urdf_document` writes is a ``<robot>`` element holding the joint, which
``<xacro:include filename="..."/>`` inserts into a robot description. No rclpy.
"""

from __future__ import annotations

import os
import re
from typing import Optional

from ..core.rigid.quaternion import matrix_from_quaternion, rpy_from_matrix
from .calibration import Calibration
from .escape import xml_attribute, xml_comment

#: The namespace of xacro's elements (``xmlns:xacro`` of the document's ``<robot>``).
XACRO_NAMESPACE = "http://www.ros.org/wiki/xacro"


def joint_name(cal: Calibration) -> str:
    """The default joint name: ``PARENT_to_CHILD``, each character that is not a letter, digit
    or ``_`` as ``_`` (``world_to_tracker``)."""
    return re.sub(r"\W", "_", f"{cal.parent_frame}_to_{cal.child_frame}", flags=re.ASCII)


def origin_values(cal: Calibration) -> tuple[tuple[float, float, float],
                                             tuple[float, float, float]]:
    """``(xyz [m], rpy [rad])`` of the calibration's transform (URDF ``<origin>``)."""
    rpy = rpy_from_matrix(matrix_from_quaternion(cal.rotation))
    return tuple(float(v) + 0.0 for v in cal.translation), rpy   # type: ignore[return-value]


def _numbers(values: tuple[float, ...]) -> str:
    return " ".join(repr(float(v) + 0.0) for v in values)   # repr: every digit, no -0.0


def urdf_joint(cal: Calibration, name: Optional[str] = None, indent: str = "") -> str:
    """The fixed ``<joint>`` element of ``cal`` (lines ending in ``\\n``): ``name`` (default
    :func:`joint_name`), ``<parent link=parent_frame/>``, ``<child link=child_frame/>`` and
    ``<origin xyz rpy/>``.

    :raises ValueError: for an empty ``name``.
    """
    name = joint_name(cal) if name is None else name
    if not name or not name.strip():
        raise ValueError("joint name must not be empty")
    xyz, rpy = origin_values(cal)
    return (f"{indent}<joint name={xml_attribute(name)} type=\"fixed\">\n"
            f"{indent}  <parent link={xml_attribute(cal.parent_frame)}/>\n"
            f"{indent}  <child link={xml_attribute(cal.child_frame)}/>\n"
            f"{indent}  <origin xyz=\"{_numbers(xyz)}\" rpy=\"{_numbers(rpy)}\"/>\n"
            f"{indent}</joint>\n")


def urdf_document(cal: Calibration, name: Optional[str] = None) -> str:
    """A URDF / xacro file of ``cal``: an XML declaration, a comment saying what it is, and a
    ``<robot>`` element (xacro namespace) holding :func:`urdf_joint`, for ``xacro:include``."""
    about = (f"{cal.child_frame} in {cal.parent_frame}: the {cal.registration} registration "
             f"of rbc_registration (decision {cal.decision.method}), created {cal.created}; "
             f"xyz in metres, rpy in radians (fixed axes X, Y, Z). Declare the link "
             f"{cal.child_frame} where the robot description has none")
    return ("<?xml version=\"1.0\"?>\n"
            f"<!-- {xml_comment(about)} -->\n"
            f"<robot xmlns:xacro=\"{XACRO_NAMESPACE}\" "
            f"name={xml_attribute(joint_name(cal) + '_calibration')}>\n"
            f"{urdf_joint(cal, name, indent='  ')}"
            "</robot>\n")


def write_urdf(path: str, cal: Calibration, name: Optional[str] = None) -> None:
    """Write :func:`urdf_document` of ``cal`` to ``path`` (missing parent directories created).

    :raises OSError: when it cannot be written.
    """
    text = urdf_document(cal, name)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)
