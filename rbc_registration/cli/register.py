"""``rbc-registration register``: register from a FIDUCIALS.csv, correct targets, report."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional, Sequence

from ..core.constants import METRES_PER_UNIT
from ..io.escape import terminal
from .options import (add_model_options, name_list, non_negative, output_file,
                      refuse_outputs_onto_inputs, unit_name, warn, warn_model,
                      warn_unit_mismatch)

if TYPE_CHECKING:   # imported when the subcommand runs (a fast --help)
    from ..core.model import ModelConfig


def add_parser(sub: Any) -> None:
    """Add ``register`` to the subparsers of ``rbc-registration``."""
    reg = sub.add_parser("register", help="register from a FIDUCIALS.csv (and correct targets)")
    reg.add_argument("fiducials", type=Path, help="CSV: id,wx,wy,wz,dx,dy,dz (2D: no wz,dz)")
    reg.add_argument("--targets", type=Path, help="CSV: id,wx,wy,wz[,dx,dy,dz]")
    add_model_options(reg, "default: 3 if the file has z", "the file's unit", defaults=True)
    reg.add_argument("--loo", action="store_true",
                     help="leave-one-out accuracy estimate over the fiducials")
    ids = name_list("fiducial ids")
    reg.add_argument("--uncorrected-fit", type=ids, metavar="IDS",
                     help="fit the uncorrected registration to these fiducial ids only")
    reg.add_argument("--corrected-fit", type=ids, metavar="IDS",
                     help="fit the corrected registration to these fiducial ids only")
    reg.add_argument("--outlier-distance", type=non_negative, metavar="D",
                     help="a repeat farther than D (the file's unit) from the mean of its id's "
                          "earlier rows: in the destination frame the file is refused (conflict), "
                          "in the working frame the row is ignored with a warning (the node's "
                          "outlier_distance); 0 = off (default: 0.25 x the fiducial spacing). "
                          "Rows of one target id farther apart than D (default: 0.25 x the "
                          "target spacing) refuse the targets file")
    reg.add_argument("--unit", default="mm", type=unit_name,
                     help=f"unit of the file (default mm): {', '.join(METRES_PER_UNIT)} (µm is "
                          f"um, inch is in); named in the report; export converts to metres "
                          f"by it")
    reg.add_argument("--json", type=output_file, metavar="OUT.json",
                     help="write the report as JSON")
    reg.set_defaults(func=run)


def model_config(args: argparse.Namespace, dimension: int,
                 ids: Sequence[str] = ()) -> "ModelConfig":
    """The core ``ModelConfig`` from the model options (and fiducial-id subsets).

    :raises ValueError: naming an unknown fiducial id of a subset.
    """
    from ..core.model import ModelConfig

    def indices(subset: Optional[Sequence[str]], name: str) -> Optional[tuple[int, ...]]:
        if not subset:
            return None
        missing = [s for s in subset if s not in ids]
        if missing:
            raise ValueError(f"{name}: unknown fiducial id(s) {', '.join(missing)}")
        return tuple(ids.index(s) for s in subset)

    return ModelConfig(dimension=dimension, restoration=args.restoration, steps=args.steps,
                       interpolation=args.interpolation, sigma=args.sigma,
                       sigma_axis=args.sigma_axis, decision=args.decision,
                       uncorrected_subset=indices(args.uncorrected_fit, "--uncorrected-fit"),
                       corrected_subset=indices(args.corrected_fit, "--corrected-fit"))


def run(args: argparse.Namespace) -> int:
    """Print the report, write JSON."""
    from ..core.decision.evaluation import describe_misfits, gross_misfits, leave_one_out
    from ..core.model import build_model
    from ..io.csv_io import read_targets, target_sessions
    from ..io.csv_stream import read_fiducial_sums
    from ..io.report import format_report, model_report, write_json

    refuse_outputs_onto_inputs([("--json", args.json)], [("fiducials", args.fiducials),
                                                          ("--targets", args.targets)])
    # read as a stream: per-fiducial means and repeat statistics, memory flat in the rows
    fid = read_fiducial_sums(args.fiducials, args.dim, args.outlier_distance,
                             target_sessions(args.targets), progress=True)
    for note in fid.notes:
        warn("register", note)
    cfg = model_config(args, fid.dimension, fid.ids)
    try:
        model = build_model(fid.working, fid.destination, cfg, ids=fid.ids,
                            repeat_statistics=fid.repeat_stats, groups=fid.groups)
    except ValueError as exc:   # name a fiducial the model cannot be built with, if one stands out
        flagged, misfit = gross_misfits(fid.working, fid.destination, floor=0.0)
        if not len(flagged):
            raise
        raise ValueError(f"{exc}; likely through "
                         f"{describe_misfits(fid.ids, misfit, flagged, args.unit)}: a typo or "
                         f"a wrong hole? fix or remove its rows") from None
    tgt = read_targets(args.targets, fid.dimension, args.outlier_distance,
                       fiducials=fid.working, sessions=fid.sessions) if args.targets else None
    if tgt is not None and tgt.destination is not None:
        from ..pipeline.offline import truth_note

        note = truth_note(tgt.ids, tgt.destination)      # some rows without truth
        if note:
            warn("register", f"{args.targets}: {note}")
    loo = leave_one_out(model) if args.loo else None
    report = model_report(model, tgt.ids if tgt else (), tgt.working if tgt else None,
                          tgt.destination if tgt else None, loo, args.unit)
    if fid.sessions is not None:
        report["sessions"] = fid.sessions.to_list()
    print(format_report(report))
    warn_unit_mismatch("register", model.working, tgt.working if tgt else None, report,
                       model.destination, tgt.destination if tgt else None)
    warn_model("register", model, args.unit)
    if args.json:
        write_json(report, args.json)
        print(f"wrote {terminal(args.json)}")
    return 0
