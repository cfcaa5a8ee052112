"""``rbc-registration reproduce``: the paper's Table 1 and Figs 2-5 on synthetic cells."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..core.constants import CELLS, MAX_REPEATS, MIN_REPRODUCE_REPEATS
from .options import integer_in, name_list, refuse_outputs_onto_inputs, seed


def add_parser(sub: Any) -> None:
    """Add ``reproduce`` to the subparsers of ``rbc-registration``."""
    rep = sub.add_parser("reproduce", help="Table 1 and Figs 2-5 on synthetic cells A, B, RA")
    rep.add_argument("--out", type=Path, default=Path("reproduce_out"), help="output directory")
    rep.add_argument("--seed", type=seed, default=0)
    rep.add_argument("--repeats", type=integer_in(MIN_REPRODUCE_REPEATS, MAX_REPEATS),
                     help="repeated measurements N (default: 200 for A and B, 16 for RA's "
                          "repeated holes)")
    rep.add_argument("--instantaneous", type=integer_in(1, MAX_REPEATS), metavar="N",
                     help="process only N of the repeated datasets one by one (default: all)")
    rep.add_argument("--cells", type=name_list("cells"), default=CELLS,
                     help=f"comma-separated subset of {','.join(CELLS)}")
    rep.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the cells, print and write everything; exit 1 when a finding does not hold."""
    from ..io.reproduce import reproduce

    refuse_outputs_onto_inputs([("--out", args.out)], [], directories=["--out"])
    doc = reproduce(args.out, seed=args.seed, repeats=args.repeats,
                    instantaneous_sets=args.instantaneous, cells=args.cells)
    failed = [f["finding"] for f in doc["findings"] if not f["holds"]]
    return 1 if failed else 0
