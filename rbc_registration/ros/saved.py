"""Saved calibrations in the node: ``~/save`` writes ``state_dir/calibration.yaml``, or
``state_dir/calibrations/NAME.yaml`` with ``calibration_name`` NAME
(:mod:`rbc_registration.io.calibration`), and ``calibration_file`` (a path, or such a NAME) is
loaded at start and published as a ``TransformStamped`` until a live model replaces it; its
``answers`` answer ``~/correct_target(s)`` meanwhile. Units: metres (REP 103).
"""

from __future__ import annotations

import os
from typing import NamedTuple, Optional

from builtin_interfaces.msg import Time
from geometry_msgs.msg import TransformStamped

from ..io.calibration import Calibration, read_calibration, static_transform_publisher_command
from ..io.calibration import write_calibration
from ..core.saved_model import SavedModel
from ..io.calibration_model import (calibration_from_state, calibration_path, check_matches,
                                    named_calibration_path, resolve_calibration_file)
from ..pipeline.settings import Settings
from ..pipeline.state import ModelState


#: Appended to the decision's method in the answers of a loaded calibration (``method`` of
#: ``CorrectTarget`` and ``TargetCorrection``: ``kriging (calibration file)``).
FROM_FILE = " (calibration file)"


class Loaded(NamedTuple):
    """A calibration file the node publishes until it has a live model; ``model`` answers
    targets from its ``answers`` (None: ``missing`` says why it answers none)."""

    path: str
    calibration: Calibration
    model: Optional[SavedModel] = None
    missing: str = ""

    def note(self) -> str:
        """The ``message`` of an answer from the file: its method, the decision and the file."""
        c = self.calibration
        d = c.decision
        return (f"{d.method}{FROM_FILE}: corrections {'applied' if d.apply else 'not applied'} "
                f"(decision {d.mode}); {d.reason}; from {self.path} (created {c.created})")

    def describe(self) -> str:
        """``calibration from PATH (...)``: what ``~/status`` says meanwhile."""
        c = self.calibration
        return (f"calibration from {self.path} ({c.registration}, {c.n_fiducials} fiducials, "
                f"created {c.created}); no live model yet")


def load(path: str, settings: Settings) -> Loaded:
    """Read ``calibration_file`` (a path, or a name in ``state_dir/calibrations``), check it
    belongs to the node's frames and dimension, and build the model of its answers.

    :raises ValueError: one line naming the file and the field.
    """
    full = resolve_calibration_file(path, settings.state_dir)
    cal = read_calibration(full)
    check_matches(cal, full, settings.working_frame, settings.destination_frame,
                  settings.dimension)
    if cal.answers is None:
        return Loaded(full, cal, None, (
            f"{full} holds no answers (the fiducials and corrections that answer targets: "
            f"answers is null, or the file is of format_version 1 or 2): it publishes tf and "
            f"answers no targets; ~/save of a live model writes them"))
    try:
        model = cal.answers.model(cal.sigma)
    except ValueError as exc:
        raise ValueError(f"{full}: answers: {exc}") from None
    return Loaded(full, cal, model)


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
    ``tf_broadcast`` publishes; ``corrected`` when it is ``none``): ``calibration.yaml``, or
    ``calibrations/NAME.yaml`` with ``calibration_name`` NAME.

    :return: ``(path, static_transform_publisher command)``.
    :raises ValueError: without a model.
    :raises OSError: when it cannot be written.
    """
    registration = "uncorrected" if settings.tf_broadcast == "uncorrected" else "corrected"
    cal = calibration_from_state(state, settings, registration)
    path = (named_calibration_path(settings.state_dir, settings.calibration_name)
            if settings.calibration_name else calibration_path(settings.state_dir))
    os.makedirs(os.path.dirname(path), exist_ok=True)
    write_calibration(path, cal)
    return path, static_transform_publisher_command(cal)
