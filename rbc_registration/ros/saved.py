"""Saved calibrations in the node: ``~/save`` writes ``state_dir/calibration.yaml``
(:mod:`rbc_registration.io.calibration`), and ``calibration_file`` is loaded at start and
published as a ``TransformStamped`` until a live model replaces it. Units: metres (REP 103).
"""

from __future__ import annotations

import os
from typing import NamedTuple

from builtin_interfaces.msg import Time
from geometry_msgs.msg import TransformStamped

from ..io.calibration import Calibration, read_calibration, static_transform_publisher_command
from ..io.calibration import write_calibration
from ..io.calibration_model import calibration_from_state, calibration_path, check_matches
from ..pipeline.settings import Settings
from ..pipeline.state import ModelState


class Loaded(NamedTuple):
    """A calibration file the node publishes until it has a live model."""

    path: str
    calibration: Calibration

    def describe(self) -> str:
        """``calibration from PATH (...)``: what ``~/status`` says meanwhile."""
        c = self.calibration
        return (f"calibration from {self.path} ({c.registration}, {c.n_fiducials} fiducials, "
                f"created {c.created}); no live model yet")


def load(path: str, settings: Settings) -> Loaded:
    """Read ``calibration_file`` and check it belongs to the node's frames and dimension.

    :raises ValueError: one line naming the file and the field.
    """
    full = os.path.abspath(os.path.expanduser(path))
    cal = read_calibration(full)
    check_matches(cal, full, settings.working_frame, settings.destination_frame,
                  settings.dimension)
    return Loaded(full, cal)


def calibration_transform(cal: Calibration, stamp: Time) -> TransformStamped:
    """``cal`` as tf uses it: ``header.frame_id`` = parent (destination), ``child_frame_id`` =
    child (working)."""
    msg = TransformStamped()
    msg.header.stamp = stamp
    msg.header.frame_id, msg.child_frame_id = cal.parent_frame, cal.child_frame
    t, r = msg.transform.translation, msg.transform.rotation
    t.x, t.y, t.z = cal.translation
    r.x, r.y, r.z, r.w = cal.rotation
    return msg


def save(state: ModelState, settings: Settings) -> tuple[str, str]:
    """Write the calibration of the served model into ``state_dir`` (the registration
    ``tf_broadcast`` publishes; ``corrected`` when it is ``none``).

    :return: ``(path, static_transform_publisher command)``.
    :raises ValueError: without a model.
    :raises OSError: when it cannot be written.
    """
    registration = "uncorrected" if settings.tf_broadcast == "uncorrected" else "corrected"
    cal = calibration_from_state(state, settings, registration)
    path = calibration_path(settings.state_dir)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    write_calibration(path, cal)
    return path, static_transform_publisher_command(cal)
