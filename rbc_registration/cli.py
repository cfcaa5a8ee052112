"""The ``rbc-registration`` command: register from CSV, reproduce the paper on synthetic cells.

Errors in the input end the command with a one-line message naming what was wrong (exit 2),
never a traceback.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Optional, Sequence

from . import commands


def _subset(text: str) -> tuple[str, ...]:
    ids = tuple(s.strip() for s in text.split(",") if s.strip())
    if not ids:
        raise argparse.ArgumentTypeError("expected a comma-separated list of fiducial ids")
    return ids


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
    parser = argparse.ArgumentParser(
        prog="rbc-registration",
        description="Rigid registration from fiducial pairs, improved by restoring the "
                    "rigid-body condition (NISTIR 8180).")
    sub = parser.add_subparsers(dest="command", required=True)

    reg = sub.add_parser("register", help="register from a FIDUCIALS.csv (and correct targets)")
    reg.add_argument("fiducials", type=Path, help="CSV: id,wx,wy,wz,dx,dy,dz (2D: no wz,dz)")
    reg.add_argument("--targets", type=Path, help="CSV: id,wx,wy,wz[,dx,dy,dz]")
    _model_options(reg)
    reg.add_argument("--loo", action="store_true",
                     help="leave-one-out accuracy estimate over the fiducials")
    reg.add_argument("--uncorrected-fit", type=_subset, metavar="IDS",
                     help="fit the uncorrected registration to these fiducial ids only")
    reg.add_argument("--corrected-fit", type=_subset, metavar="IDS",
                     help="fit the corrected registration to these fiducial ids only")
    reg.add_argument("--unit", default="mm", help="unit of the file, used as a label (default mm)")
    reg.add_argument("--json", type=Path, metavar="OUT.json", help="write the report as JSON")
    reg.set_defaults(func=commands.register)

    rep = sub.add_parser("reproduce", help="Table 1 and Figs 2-5 on synthetic cells A, B, RA")
    rep.add_argument("--out", type=Path, default=Path("reproduce_out"), help="output directory")
    rep.add_argument("--seed", type=int, default=0)
    rep.add_argument("--repeats", type=int, help="repeated measurements N (default: 200 for "
                                                 "A and B, 16 for RA's repeated holes)")
    rep.add_argument("--instantaneous", type=int, metavar="N",
                     help="process only N of the repeated datasets one by one (default: all)")
    rep.add_argument("--cells", default="A,B,RA", help="comma-separated subset of A,B,RA")
    rep.set_defaults(func=commands.reproduce)
    from .bag_commands import add_parsers  # noqa: E402 - evaluate, replay, synth-bag
    add_parsers(sub)
    return parser


def _model_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dim", type=int, choices=(2, 3), help="default: 3 if the file has z")
    p.add_argument("--sigma", type=float, help="noise sigma of one measurement (RMS over all "
                                               "axes); default: from repeated rows")
    p.add_argument("--restoration", choices=("iterative", "closed-form"), default="iterative")
    p.add_argument("--steps", type=int, default=2, help="iterative steps (default 2)")
    p.add_argument("--interpolation", choices=("paper", "kriging"), default="paper")


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point of the console script; returns the exit code."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except ValueError as exc:          # bad input: one clear line, no traceback
        print(f"rbc-registration {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"rbc-registration {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
