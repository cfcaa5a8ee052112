"""``rbc-registration export``: a calibration file (docs/CALIBRATION.md) from the node's snapshot
(``state_dir/calibration.json``) or a ``register`` / ``evaluate --json`` report, and the forms
ROS users load: the ``static_transform_publisher`` line, a launch snippet and, with ``--urdf``,
a URDF / xacro fixed joint (``<origin xyz rpy>``, metres and radians)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..core.constants import METRES_PER_UNIT, UNCORRECTED
from ..io.escape import terminal
from .options import output_file, refuse_outputs_onto_inputs, unit_name

#: The registrations of a model ``--registration`` chooses from.
REGISTRATIONS = ("corrected", UNCORRECTED)

#: Largest report or snapshot read (a snapshot of 100,000 fiducials is ~30 MB).
MAX_SOURCE_BYTES = 256 << 20


def add_parser(sub: Any) -> None:
    """Add ``export`` to the subparsers of ``rbc-registration``."""
    exp = sub.add_parser("export", help="write a calibration YAML from a node snapshot or a "
                                        "JSON report; print the static_transform_publisher line")
    exp.add_argument("source", type=Path, metavar="SNAPSHOT_OR_REPORT.json",
                     help="state_dir/calibration.json of the node, or a register/evaluate --json "
                          "report")
    exp.add_argument("--out", type=output_file, default=Path("calibration.yaml"),
                     help="the calibration file to write (default calibration.yaml)")
    exp.add_argument("--registration", choices=REGISTRATIONS,
                     help="which registration of the model (default: the decision's, corrected "
                          "only when its corrections are applied); the output says which")
    exp.add_argument("--parent-frame", help="destination frame (default: the snapshot's or an "
                                            "evaluate report's; a register report: world, "
                                            "with a warning)")
    exp.add_argument("--child-frame", help="working frame (default: the snapshot's or an "
                                           "evaluate report's; a register report: tracker, "
                                           "with a warning)")
    exp.add_argument("--unit", type=unit_name, metavar="{" + ",".join(METRES_PER_UNIT) + "}",
                     help="length unit of a source that records none (µm is um, inch is in); "
                          "a report's 'unit' (a "
                          "snapshot: metres) is used, and a different --unit is refused; the "
                          "file is in metres")
    exp.add_argument("--urdf", type=output_file, metavar="OUT.urdf.xacro",
                     help="also write the registration as a URDF / xacro fixed joint (parent "
                          "link = parent frame, child link = child frame, <origin xyz rpy> in "
                          "metres and radians) and print the joint; xacro:include it")
    exp.add_argument("--joint-name", metavar="NAME",
                     help="name of the --urdf joint (default PARENT_to_CHILD)")
    exp.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write the YAML (and the --urdf joint), print the static_transform_publisher line and the
    launch snippet (and the joint)."""
    import json
    import sys

    from ..io.calibration import (expected_errors, launch_snippet,
                                  static_transform_publisher_command, write_calibration)
    from ..io.calibration_model import calibration_from_document
    from ..pipeline.files import check_input_file

    if args.joint_name is not None and args.urdf is None:
        raise ValueError("--joint-name names the --urdf joint: give --urdf OUT.urdf.xacro too")
    if args.joint_name is not None and not args.joint_name.strip():
        raise ValueError("--joint-name must not be empty")
    refuse_outputs_onto_inputs([("--out", args.out), ("--urdf", args.urdf)],
                               [("source", args.source)])
    where = str(args.source)
    try:
        check_input_file(where, MAX_SOURCE_BYTES)      # NotARegularFile: a ValueError, as is
        text = args.source.read_text(encoding="utf-8")
        mtime = args.source.stat().st_mtime
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{where}: cannot be read: {exc}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{where}: not valid JSON: {exc}") from None
    registration, which = _registration(data, args.registration)
    cal = calibration_from_document(
        data, where, registration, parent_frame=args.parent_frame,
        child_frame=args.child_frame, unit=args.unit, mtime=mtime,
        note=lambda line: print(f"rbc-registration export: warning: {terminal(line)}",
                                file=sys.stderr))
    write_calibration(str(args.out), cal)
    print(f"wrote {terminal(args.out)}")
    print(which)
    print(expected_errors(cal))
    print(static_transform_publisher_command(cal))
    print()
    print(launch_snippet(cal), end="")
    if args.urdf is not None:
        from ..io.urdf import urdf_joint, write_urdf

        write_urdf(str(args.urdf), cal, args.joint_name)
        print()
        print(f"wrote {terminal(args.urdf)}: xacro:include it, or paste the joint into the URDF")
        print(urdf_joint(cal, args.joint_name), end="")
    return 0


def _registration(data: Any, given: str | None) -> tuple[str, str]:
    """The registration to export and the line saying which: ``given`` (``--registration``), or
    the decision's (``corrected`` only when the source's ``decision.apply`` is true). For a
    source without a readable decision the line is not printed: reading it says what is wrong
    (its ``decision``, or the registration missing)."""
    decision = data.get("decision") if isinstance(data, dict) else None
    if not isinstance(decision, dict) or not isinstance(decision.get("apply"), bool):
        return given or "corrected", ""
    applied = decision["apply"]
    chosen = "corrected" if applied else UNCORRECTED
    method = terminal(str(decision.get("method", "?")))
    its = f"{method}, corrections {'applied' if applied else 'not applied'}"
    if given is None:
        return chosen, (f"registration {chosen}: the decision's ({its}); --registration "
                        f"{'uncorrected' if applied else 'corrected'} exports the other")
    return given, (f"registration {given} (--registration); the decision's is {chosen} "
                   f"({its})")
