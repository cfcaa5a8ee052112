"""Argument types and option groups shared by several subcommands (standard library only)."""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path
from typing import Any, Callable, Iterable, NoReturn, Optional, Sequence

from ..core.constants import (DECISION_MODES, DIMENSIONS, INTERPOLATIONS, METRES_PER_UNIT,
                              RESTORATIONS, length_unit)
from ..io.escape import terminal


class OneLineParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line (``PROG: error: TEXT``, exit 2), like the
    errors of the subcommands; ``--help`` shows the usage."""

    def error(self, message: str) -> "NoReturn":  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {terminal(message)} (see --help)\n")


def output_file(text: str) -> Path:
    """An argument type: the path of a file to write. A name ending in a path separator (or in
    ``.`` or ``..``) names a directory (``Path`` drops the separator, and ``--json out/`` or
    ``--json out/.`` wrote a file ``out``)."""
    if not text or text.endswith(("/", os.sep)) or os.path.basename(text) in (".", ".."):
        raise argparse.ArgumentTypeError(f"{text!r} names a directory, not a file: add the "
                                         f"file's name")
    return Path(text)


def _number(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None


def number_in(low: float, high: float) -> Callable[[str], float]:
    """An argument type: a number in ``[low, high]`` (NaN and inf refused)."""
    def parse(text: str) -> float:
        value = _number(text)
        if not low <= value <= high:     # False for NaN
            raise argparse.ArgumentTypeError(f"must be in [{low:g}, {high:g}], got {text!r}")
        return value
    return parse


def integer_in(low: int, high: int) -> Callable[[str], int]:
    """An argument type: an integer in ``[low, high]``."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or not low <= value <= high:
            raise argparse.ArgumentTypeError(f"must be an integer in [{low}, {high}], "
                                             f"got {text!r}")
        return value
    return parse


#: ``--seed``: what numpy's generators take.
seed = integer_in(0, 2**64 - 1)


def unit_name(text: str) -> str:
    """An argument type: a length unit of :data:`~rbc_registration.core.constants.
    METRES_PER_UNIT` (an alias, e.g. ``µm``, as its unit: ``um``)."""
    try:
        return length_unit(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def non_negative(text: str) -> float:
    """A finite number >= 0."""
    value = _number(text)
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0 and finite, got {text!r}")
    return value


def warn(command: str, text: str) -> None:
    """One warning line on stderr, ``rbc-registration COMMAND: warning: TEXT``."""
    print(f"rbc-registration {command}: warning: {terminal(text)}", file=sys.stderr)


def warn_unit_mismatch(command: str, fiducials: object, targets: object, report: dict,
                       destination: object = None, truth: object = None) -> None:
    """One warning line per line of :func:`unit_mismatch_lines`."""
    for line in unit_mismatch_lines(fiducials, targets, report, destination, truth):
        warn(command, line)


def unit_mismatch_lines(fiducials: object, targets: object, report: dict,
                        destination: object = None, truth: object = None) -> list[str]:
    """One line when every target is out of the hull at a scale ~100x or more off the
    fiducials' (:func:`rbc_registration.core.rigid.scale.unit_mismatch`); another when the targets'
    truth is that far off the fiducials' destination points, or else when some targets' truth
    stands out (:func:`rbc_registration.core.decision.evaluation.describe_truth_blunders`).

    :param fiducials: the model's fiducials, working frame; :param targets: the report's
        targets, working frame (``None``: none); :param report: the report (its hull flags);
    :param destination: the fiducials in the destination frame; :param truth: the targets'
        true points there (``None``: no truth).
    """
    from ..core.decision.evaluation import describe_truth_blunders
    from ..core.rigid.scale import unit_mismatch

    if targets is None or not report.get("targets"):
        return []
    lines = []
    text = unit_mismatch(fiducials, targets, [t["inside_hull"] for t in report["targets"]])
    if text:
        lines.append(text)
    if truth is not None and destination is not None:
        import numpy as np

        from ..pipeline.targets import with_truth

        truth = np.asarray(truth, dtype=float)
        truth = truth[with_truth(truth, len(truth))]
    if truth is not None and destination is not None and len(truth):
        # no hull in the destination frame: the size ratio alone (100x) decides
        text = unit_mismatch(destination, truth, None, "target truth")
        if text:
            lines.append("the targets' truth: " + text)
        elif "tre_u" in report["targets"][0]:   # one unit: a target's truth that stands out
            known = [t for t in report["targets"] if t["tre_u"] is not None]
            text = describe_truth_blunders([t["id"] for t in known], [t["tre_u"] for t in known],
                                           report.get("unit", ""))
            if text:
                lines.append(text)
    return lines


def warn_model(command: str, model: Any, unit: str) -> None:
    """The warnings of a model built from a fiducials file (``register``, ``plan``), one line
    each: :func:`~rbc_registration.core.warnings.model_warnings`, and a cell too large or too
    small for ``unit`` (:func:`~rbc_registration.core.rigid.scale.implausible_size`)."""
    from ..core.rigid.scale import implausible_size
    from ..core.warnings import model_warnings

    for line in model_warnings(model, unit):
        warn(command, line)
    if unit in METRES_PER_UNIT:
        size = implausible_size(model.destination, METRES_PER_UNIT[unit], unit)
        if size:
            warn(command, size)


def node_name(text: str) -> str:
    """An argument type: a valid ROS node name (``--node-name``; the topics are
    ``/NAME/...``)."""
    from ..io.bag.records import node_name_error

    error = node_name_error(text)
    if error:
        raise argparse.ArgumentTypeError(error)
    return text


def frame_id(text: str) -> str:
    """An argument type: a tf frame id (:func:`rbc_registration.core.frames.frame_id_problem`,
    the node's rule for its frame parameters)."""
    from ..core.frames import frame_id_problem

    problem = frame_id_problem(text)
    if problem:
        raise argparse.ArgumentTypeError(f"{text!r}: a frame id {problem}")
    return text


def name_list(what: str) -> Callable[[str], tuple[str, ...]]:
    """An argument type: a comma-separated, non-empty list of ``what`` (e.g. fiducial ids)."""
    def parse(text: str) -> tuple[str, ...]:
        names = tuple(s.strip() for s in text.split(",") if s.strip())
        if not names:
            raise argparse.ArgumentTypeError(f"expected a comma-separated list of {what}")
        return names
    return parse


def add_model_options(p: argparse.ArgumentParser, dim_help: str, unit: str,
                      defaults: bool) -> None:
    """``--dim``, ``--sigma`` / ``--sigma-axis`` (one of them), ``--decision``,
    ``--restoration``, ``--steps``, ``--interpolation``.

    :param unit: the length unit of sigma, for the help text (``the file's unit``, ``m``).
    :param defaults: give the core's defaults (``register``); else ``None``, so that the node
        parameters decide (``evaluate``).
    """
    p.add_argument("--dim", type=int, choices=DIMENSIONS, help=dim_help)
    noise = p.add_mutually_exclusive_group()
    noise.add_argument("--sigma", type=float, metavar="S",
                       help=f"known noise [{unit}] of one measurement: RMS distance from the "
                            f"true point, all axes together (the paper's rho = sigma_L0 / "
                            f"sigma uses it); default: from repeated measurements")
    noise.add_argument("--sigma-axis", type=float, metavar="S",
                       help=f"known noise [{unit}] per axis (sigma = S * sqrt(dim)); not with "
                            f"--sigma")
    p.add_argument("--decision", choices=DECISION_MODES,
                   default=DECISION_MODES[0] if defaults else None,
                   help="whether and how targets get corrections: cv (default; "
                        "cross-validated on the fiducials, needs no sigma), rho (the paper's "
                        "rule, needs sigma), on, off")
    p.add_argument("--restoration", choices=RESTORATIONS,
                   default=RESTORATIONS[0] if defaults else None)
    steps: Optional[int] = 2 if defaults else None
    p.add_argument("--steps", type=int, default=steps, help="iterative steps (default 2)")
    p.add_argument("--interpolation", choices=INTERPOLATIONS,
                   default=INTERPOLATIONS[0] if defaults else None,
                   help="interpolation of the corrections (paper eq. 5): what 'corrected' "
                        "reports, and what decisions rho and on apply; cv chooses among both")


def _same_file(a: Path, b: Path) -> bool:
    """Whether two paths name one file (symlinks, hard links, relative spellings)."""
    try:
        return os.path.samefile(a, b)
    except OSError:         # one of them does not exist (yet)
        return os.path.realpath(a) == os.path.realpath(b)


def _with_children(path: Path) -> Iterable[Path]:
    """The path and, for a directory (a bag), the files directly inside it."""
    yield path
    if path.is_dir():
        try:
            yield from sorted(path.iterdir())[:1000]
        except OSError:
            pass


def unwritable(out: Path, directory: bool = False) -> str:
    """Why the output ``out`` (a file, or with ``directory`` a directory) cannot be written, or
    "" (checked before a long run; the write itself may still fail, e.g. on a full disk). Missing
    parent directories are created by the writers (``write_json``, ``write_calibration``, the
    figures, ``--out DIR``): the nearest existing one must be a writable directory."""
    if out.exists():
        if directory != out.is_dir():
            return "it is a directory" if out.is_dir() else "it exists and is not a directory"
        if not os.access(out, os.W_OK | (os.X_OK if directory else 0)):
            return "it is not writable"
        if directory:
            return ""
    ancestor = out.parent
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        return f"{terminal(str(ancestor))} is not a directory"
    return "" if os.access(ancestor, os.W_OK | os.X_OK) else \
        f"its directory {terminal(str(ancestor))} is not writable"


def _inside(path: Path, directory: Path) -> bool:
    try:
        return path.resolve().is_relative_to(directory.resolve())
    except (OSError, RuntimeError):
        return False


def refuse_outputs_onto_inputs(outputs: Sequence[tuple[str, Optional[Path]]],
                               inputs: Sequence[tuple[str, Optional[Path]]],
                               directory_files: Sequence[str] = (),
                               directories: Sequence[str] = ()) -> None:
    """Refuse, before anything is written (and before a long run), an output that is one of the
    inputs or inside an input directory (a bag), two outputs that are one file, and an output
    that cannot be written (:func:`unwritable`).

    :param outputs: ``(option, path)`` of every output (``None``: not given).
    :param inputs: ``(what, path)`` of every input (``None``: not given); a directory input (a
        bag) counts with the files in it.
    :param directory_files: names of the files written into an output directory (``--out DIR``
        of ``evaluate``): each of them is an output too (of every output: a file has none).
    :param directories: the options of ``outputs`` that name a directory (created if missing).
    :raises ValueError: naming the option, the output and the input it would overwrite, or why
        it cannot be written.
    """
    for option, out in outputs:
        if out is None:
            continue
        candidates = [out] + [out / name for name in directory_files]
        for what, given in inputs:
            if given is None:
                continue
            if given.is_dir() and _inside(out, given):
                raise ValueError(f"{option} {terminal(str(out))} is inside the input {what} "
                                 f"{terminal(str(given))}: refusing to write into an input "
                                 "directory")
            for src in _with_children(given):
                for dst in candidates:
                    if _same_file(dst, src):
                        same = "" if dst == out else f" (it would write {dst})"
                        raise ValueError(f"{option} {out} is the input {what} {src}{same}: "
                                         "refusing to overwrite an input")
    given = [(option, out, [out] + [out / name for name in directory_files])
             for option, out in outputs if out is not None]
    for k, (option, out, mine) in enumerate(given):
        for other, path, theirs in given[k + 1:]:
            if any(_same_file(a, b) for a in mine for b in theirs):
                raise ValueError(f"{option} {out} and {other} {path} are the same file (or one "
                                 "writes into the other): one would overwrite the other")
    for option, out in outputs:
        why = "" if out is None else unwritable(out, option in directories)
        if why:
            raise ValueError(f"{option} {terminal(str(out))} cannot be written: {why}")
