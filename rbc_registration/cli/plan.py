"""``rbc-registration plan``: which fiducial to measure next, and when there are enough.

Builds the model of FIDUCIALS.csv as ``register`` does (same model options), then ranks the
candidate locations of CANDIDATES.csv by the expected reduction of the median target error
(:func:`rbc_registration.core.planning.model_planner.plan_from_model`; docs/METHOD.md, "Planning the
measurements"), over the targets of TARGETS.csv or, without them, over the work volume.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..core.constants import METRES_PER_UNIT
from ..io.escape import terminal
from .options import (add_model_options, non_negative, output_file, refuse_outputs_onto_inputs,
                      unit_name, warn, warn_model)

#: Suggestions made when ``--count`` is not given (fewer when there are fewer candidates).
DEFAULT_COUNT = 5
#: The option of each PlanConfig field the command sets.
_OPTIONS = {"within": "--within", "min_gain_fraction": "--min-gain-fraction",
            "min_gain_length": "--min-gain",
            "candidate_repeats": "--candidate-repeats", "target_repeats": "--target-repeats"}


def add_parser(sub: Any) -> None:
    """Add ``plan`` to the subparsers of ``rbc-registration``."""
    p = sub.add_parser("plan", help="rank candidate fiducials by the expected gain at the "
                                    "targets; say when there are enough")
    p.add_argument("fiducials", type=Path, help="CSV: id,wx,wy,wz,dx,dy,dz (2D: no wz,dz): the "
                                                "fiducials measured so far")
    p.add_argument("--candidates", type=Path, required=True,
                   help="CSV: id,wx,wy[,wz][,group]: locations that could be measured next "
                        "(working frame; approximate is enough); a group (e.g. a robot pose) "
                        "is ranked and measured as a whole; at most 1,000,000 rows "
                        "(io.csv_io.MAX_CANDIDATE_ROWS)")
    p.add_argument("--targets", type=Path, help="CSV: id,wx,wy[,wz]: the targets that matter "
                                                "(default: the work volume)")
    p.add_argument("--count", type=int, help=f"suggestions in order, each conditioned on the "
                                             f"previous ones (default {DEFAULT_COUNT}, at most "
                                             f"the candidates)")
    p.add_argument("--within", type=float, default=0.10, metavar="F",
                   help="enough when the expected median target error is within this fraction "
                        "of what measuring every candidate is expected to give (default 0.10; "
                        "0: off)")
    p.add_argument("--min-gain-fraction", type=float, default=0.0, metavar="F",
                   help="... or when the best next candidate (or group) gains less than this "
                        "fraction of the expected median target error (default 0: off)")
    p.add_argument("--min-gain", type=float, default=0.0, metavar="LENGTH",
                   help="... or less than this length, unit of the files (default 0: off)")
    add_model_options(p, "default: 3 if the file has z", "the file's unit", defaults=True)
    p.add_argument("--outlier-distance", type=non_negative, metavar="D",
                   help="repeats of FIDUCIALS.csv checked as by register (default: 0.25 x the "
                        "fiducial spacing; 0 = off); rows of one candidate or target id farther "
                        "apart than D (default: 0.25 x their spacing) refuse that file")
    p.add_argument("--candidate-repeats", type=int, metavar="N",
                   help="measurements to be averaged into each new fiducial (default: the "
                        "median repeat count of FIDUCIALS.csv's ids)")
    p.add_argument("--target-repeats", type=int, metavar="N",
                   help="measurements to be averaged into each target (default: the median "
                        "rows per id of TARGETS.csv; without it, as --candidate-repeats)")
    p.add_argument("--unit", default="mm", type=unit_name,
                   help=f"unit of the files (default mm): {', '.join(METRES_PER_UNIT)} (µm is "
                        f"um, inch is in), as register takes; named in the report")
    p.add_argument("--json", type=output_file, metavar="OUT.json", help="write the plan as JSON")
    p.add_argument("--figure", type=output_file, metavar="OUT.png",
                   help="draw the candidates by expected gain and the expected error against "
                        "the fiducial count")
    p.set_defaults(func=run, uncorrected_fit=None, corrected_fit=None)


def run(args: argparse.Namespace) -> int:
    """Print the plan; write JSON and the figure."""
    from dataclasses import replace

    from ..core.model import build_model
    from ..core.planning.model_planner import calibrated, plan_from_model
    from ..core.planning.planner import PlanConfig, overlap_notes, typical_repeats
    from ..io.csv_io import MAX_CANDIDATE_ROWS, read_targets, target_sessions
    from ..io.csv_stream import read_fiducial_sums
    from ..io.plan_report import format_plan, plan_report
    from ..io.report import write_json
    from .register import model_config

    if args.figure is not None and (args.figure.suffix.lower() != ".png"
                                    or args.figure.is_dir()):
        # matplotlib would add ".png" itself and write beside what was named
        raise ValueError(f"--figure {terminal(args.figure)}: must name a .png file")
    refuse_outputs_onto_inputs([("--json", args.json), ("--figure", args.figure)],
                               [("fiducials", args.fiducials), ("--candidates", args.candidates),
                                ("--targets", args.targets)])
    try:
        config = PlanConfig(within=args.within, min_gain_fraction=args.min_gain_fraction,
                            min_gain_length=args.min_gain,
                            candidate_repeats=args.candidate_repeats,
                            target_repeats=args.target_repeats)
    except ValueError as exc:             # the message names the field: name its option
        option = next((o for f, o in _OPTIONS.items() if str(exc).startswith(f)), "plan")
        raise ValueError(f"{option}: {exc}") from None
    fid = read_fiducial_sums(args.fiducials, args.dim, args.outlier_distance,
                             target_sessions(args.targets))
    for note in fid.notes:
        warn("plan", note)
    cand = read_targets(args.candidates, fid.dimension, args.outlier_distance, "candidate",
                        fid.working, sessions=fid.sessions, max_rows=MAX_CANDIDATE_ROWS)
    for note in overlap_notes(fid.working, fid.ids, cand.working, cand.ids):
        warn("plan", note)
    tgt = read_targets(args.targets, fid.dimension, args.outlier_distance,
                       fiducials=fid.working, sessions=fid.sessions) if args.targets else None
    if tgt is not None and args.target_repeats is None:
        # the targets file's own rows per id: how often each target is measured
        config = replace(config, target_repeats=typical_repeats(tgt.counts))
    units = len(set(g or f"\0{k}" for k, g in enumerate(cand.groups))) if cand.groups \
        else len(cand.ids)
    count = min(DEFAULT_COUNT, units) if args.count is None else args.count
    model = build_model(fid.working, fid.destination, model_config(args, fid.dimension),
                        ids=fid.ids, repeat_statistics=fid.repeat_stats, groups=fid.groups)
    groups = cand.groups if cand.groups is not None and any(cand.groups) else None
    em, check = calibrated(model)
    plan = plan_from_model(model, cand.working, tgt.working if tgt else None, count=count,
                           config=config, error_model=em, check=check, groups=groups)
    _warn_unit_mismatch(model.working, cand.working, tgt.working if tgt else None)
    warn_model("plan", model, args.unit)
    report = plan_report(plan, cand.ids, em, config, args.unit)
    print(format_plan(report))
    if args.json:
        write_json(report, args.json)
        print(f"wrote {terminal(args.json)}")
    if args.figure:
        from ..io.figures import plan_figure
        counts, curve = plan.error_curve
        gains = [plan.gains[u] for u in _unit_of(plan, len(cand.ids))]
        plan_figure(args.figure, model.working, cand.working, gains, plan.ranked_candidates,
                    counts, curve, args.unit, tgt.working if tgt else None,
                    plan.expected_with_all)
        print(f"wrote {terminal(args.figure)}")
    return 0


def _unit_of(plan: Any, count: int) -> list[int]:
    """The unit (group) of each of ``count`` candidates of ``plan``."""
    out = list(range(count))
    for u, members in enumerate(plan.members):
        for c in members:
            out[c] = u
    return out


def _warn_unit_mismatch(fiducials: Any, candidates: Any, targets: Any) -> None:
    """One warning line for candidates, and one for targets, that lie all outside the fiducials'
    hull at a scale ~100x off theirs (:func:`rbc_registration.core.rigid.scale.unit_mismatch`)."""
    from ..core.interpolation.paper import HullTest
    from ..core.rigid.scale import point_sets_unit_mismatch

    for text in point_sets_unit_mismatch(fiducials, HullTest(fiducials),
                                         (("candidates", candidates), ("targets", targets))):
        warn("plan", text)
