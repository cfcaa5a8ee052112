"""``rbc-registration synth-bag``: a synthetic cell (A, B, RA) written as a bag (metres)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ..core.constants import CELLS, MAX_REPEATS
from ..io.bag.records import PERIODS, STORAGES, SYNTH_PERIOD_S
from ..io.escape import terminal
from .options import frame_id, integer_in, node_name, number_in, seed


def add_parser(sub: Any) -> None:
    """Add ``synth-bag`` to the subparsers of ``rbc-registration``."""
    sb = sub.add_parser("synth-bag", help="write a synthetic cell (A, B, RA) as a bag")
    sb.add_argument("out", type=Path, help="bag directory to create")
    sb.add_argument("--cell", choices=CELLS, required=True)
    sb.add_argument("--storage", choices=STORAGES, default=STORAGES[0])
    sb.add_argument("--seed", type=seed, default=0)
    sb.add_argument("--repeats", type=integer_in(1, MAX_REPEATS),
                    help="repeated measurements N (default: the cell's)")
    sb.add_argument("--period", type=number_in(*PERIODS), default=SYNTH_PERIOD_S,
                    help=f"seconds between measurements, {PERIODS[0]:g} to {PERIODS[1]:g} "
                         f"(default {SYNTH_PERIOD_S:g}: over twice the default pair_slop; "
                         "with --points, a period up to twice pair_slop makes points ambiguous)")
    sb.add_argument("--points", action="store_true",
                    help="fiducials as PointStamped pairs without ids instead of FiducialPair")
    sb.add_argument("--working-frame", type=frame_id, default="tracker",
                    help="frame id of the working points (default tracker)")
    sb.add_argument("--destination-frame", type=frame_id, default="world",
                    help="frame id of the destination points (default world); not the "
                         "working frame")
    sb.add_argument("--node-name", type=node_name, default="registration_node",
                    help="topics are /NODE_NAME/fiducial_pairs etc.")
    sb.add_argument("--quiet", action="store_true", help="no progress output")
    sb.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Write a synthetic cell as a bag."""
    from ..core.synthetic.cells import make_cell
    from ..io.bag.records import Topics
    from ..io.bag.synthetic import cell_message_count, cell_messages
    from ..io.bag.writer import write_bag

    from ..core.frames import same_frame_problem

    same = same_frame_problem("--working-frame", args.working_frame, args.destination_frame)
    if same:
        raise ValueError(f"--destination-frame {same}")
    cell = make_cell(args.cell, seed=args.seed, repeats=args.repeats)
    topics = Topics.for_node(args.node_name)
    n_fid, n_tgt, total = cell_message_count(cell, args.points)
    n = write_bag(args.out, cell_messages(cell, topics, args.working_frame,
                                          args.destination_frame, args.period, args.points),
                  args.storage, progress=not args.quiet, total=total)
    print(f"wrote {terminal(args.out)} ({args.storage}): cell {args.cell} seed {args.seed}, "
          f"{len(cell.fiducial_ids)} fiducials ({n_fid} measurements"
          f"{' as point pairs' if args.points else ''}), {len(cell.target_ids)} targets "
          f"({n_tgt} measurements) on {terminal(topics.targets)}; {n} messages, metres, "
          f"{cell.spec.dimension}D{' (z = 0)' if cell.spec.dimension == 2 else ''}")
    return 0
