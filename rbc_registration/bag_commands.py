"""The bag subcommands of ``rbc-registration``: ``evaluate`` (offline, no ROS graph), ``replay``
(into a live graph; rclpy is imported only there) and ``synth-bag`` (synthetic cells as bags).

Lengths in bags are metres (REP 103); see docs/BAGS.md.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from .io.bag import DEFAULT_TOPICS, STORAGES, OutMessage, Topics

SYNTH_START_NS = 1_700_000_000 * 1_000_000_000  # first stamp of a synthetic bag
MM_TO_M = 1e-3


def add_parsers(sub: Any) -> None:
    """Add ``evaluate``, ``replay`` and ``synth-bag`` to the subparsers of ``rbc-registration``."""
    ev = sub.add_parser("evaluate", help="evaluate a recorded bag offline, like register")
    ev.add_argument("bag", type=Path, help="rosbag2 directory, .mcap or .db3 file (metres)")
    ev.add_argument("--targets", type=Path, metavar="TARGETS.csv",
                    help="CSV in metres: id,wx,wy[,wz][,dx,dy[,dz]] (default: the targets topic)")
    ev.add_argument("--json", type=Path, metavar="OUT.json", help="write the report as JSON")
    ev.add_argument("--out", type=Path, metavar="DIR",
                    help="write report.json, report.md and PNG figures here")
    ev.add_argument("--dim", type=int, choices=(2, 3),
                    help="default: 2 when every z in the bag is 0, else 3")
    ev.add_argument("--sigma", type=float, help="known noise sigma [m] (node parameter sigma); "
                                                "default: from repeats")
    ev.add_argument("--restoration", choices=("iterative", "closed-form"))
    ev.add_argument("--steps", type=int, help="iterative steps (default 2)")
    ev.add_argument("--interpolation", choices=("paper", "kriging"))
    ev.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                    help="a registration_node parameter, e.g. -p merge_radius:=0.002 (repeatable)")
    ev.add_argument("--loo", action="store_true", help="leave-one-out estimate over fiducials")
    _topic_options(ev)
    ev.add_argument("--quiet", action="store_true", help="no progress output")
    ev.set_defaults(func=evaluate)

    rp = sub.add_parser("replay", help="publish a bag into the live ROS graph")
    rp.add_argument("bag", type=Path, help="rosbag2 directory, .mcap or .db3 file")
    rp.add_argument("--rate", type=_positive, default=1.0,
                    help="time scale: 2 plays twice as fast (default 1)")
    rp.add_argument("--loop", action="store_true", help="play again and again until Ctrl-C")
    rp.add_argument("--topics", type=_topic_list, metavar="T1,T2",
                    help="only these topics (default: every topic)")
    rp.add_argument("--wait", type=float, default=5.0, metavar="SECONDS",
                    help="wait this long at most for subscribers before playing (default 5)")
    rp.add_argument("--quiet", action="store_true", help="no progress output")
    rp.set_defaults(func=replay)

    sb = sub.add_parser("synth-bag", help="write a synthetic cell (A, B, RA) as a bag")
    sb.add_argument("out", type=Path, help="bag directory to create")
    sb.add_argument("--cell", choices=("A", "B", "RA"), required=True)
    sb.add_argument("--storage", choices=STORAGES, default="sqlite3")
    sb.add_argument("--seed", type=int, default=0)
    sb.add_argument("--repeats", type=int, help="repeated measurements N (default: the cell's)")
    sb.add_argument("--period", type=_positive, default=0.02,
                    help="seconds between measurements (default 0.02)")
    sb.add_argument("--points", action="store_true",
                    help="fiducials as PointStamped pairs without ids instead of FiducialPair")
    sb.add_argument("--working-frame", default="tracker")
    sb.add_argument("--destination-frame", default="world")
    sb.add_argument("--node-name", default="registration_node",
                    help="topics are /NODE_NAME/fiducial_pairs etc.")
    sb.add_argument("--quiet", action="store_true", help="no progress output")
    sb.set_defaults(func=synth_bag)


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return value


def _topic_list(text: str) -> tuple[str, ...]:
    topics = tuple(t.strip() for t in text.split(",") if t.strip())
    if not topics:
        raise argparse.ArgumentTypeError("expected a comma-separated list of topics")
    return topics


def _topic_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--node-name", default="registration_node",
                   help="default topics are /NODE_NAME/fiducial_pairs etc.")
    for name, what in (("fiducial", "FiducialPair"), ("working", "PointStamped, working frame"),
                       ("destination", "PointStamped, destination frame"),
                       ("targets", "FiducialPair targets with truth")):
        p.add_argument(f"--{name}-topic", metavar="TOPIC", help=f"{what} topic")


def topics_from_args(args: argparse.Namespace) -> tuple[Topics, list[str]]:
    """The topics to read and the ones named explicitly (which must exist)."""
    base = Topics.for_node(args.node_name)
    named = {"fiducial_pairs": args.fiducial_topic, "working_point": args.working_topic,
             "destination_point": args.destination_topic, "targets": args.targets_topic}
    explicit = {k: v for k, v in named.items() if v}
    return base._replace(**explicit), list(explicit.values())


def parse_params(items: list[str]) -> dict[str, Any]:
    """``NAME:=VALUE`` strings -> typed node parameters (type of the parameter's default).

    :raises ValueError: on a malformed item, an unknown name or a value of the wrong type.
    """
    from .ros.params import SPECS

    out: dict[str, Any] = {}
    for item in items:
        name, sep, text = item.partition(":=")
        name = name.strip()
        if not sep or not name:
            raise ValueError(f"-p expects NAME:=VALUE, got {item!r}")
        if name not in SPECS:
            raise ValueError(f"unknown node parameter {name!r} (known: {', '.join(SPECS)})")
        kind = type(SPECS[name].default)
        try:
            if kind is bool:
                if text.lower() not in ("true", "false"):
                    raise ValueError
                out[name] = text.lower() == "true"
            else:
                out[name] = kind(text)
        except ValueError:
            raise ValueError(f"-p {name}: expected a {kind.__name__}, got {text!r}") from None
    return out


# -- evaluate ----------------------------------------------------------------------------------
def evaluate(args: argparse.Namespace) -> int:
    """``evaluate``: bag -> node's accumulation and model -> report (stdout, JSON, directory)."""
    try:  # the node's ingestion imports the ROS message packages (not rclpy)
        from .evaluate import (Targets, evaluate_contents, infer_dimension, print_summary,
                               settings_for, write_report_dir)
    except ImportError as exc:
        raise ValueError(f"{exc}: the ROS message packages are missing; run "
                         "scripts/bootstrap.sh and source scripts/env.sh") from None
    from .io.bag import read_bag
    from .io.csv_io import read_targets
    from .io.report import write_json

    params = parse_params(args.param)
    for key, value in (("sigma", args.sigma), ("restoration", args.restoration),
                       ("restoration_steps", args.steps), ("interpolation", args.interpolation)):
        if value is not None:
            params[key] = value
    topics, required = topics_from_args(args)
    try:
        contents = read_bag(args.bag, topics, required, progress=not args.quiet)
        dim = args.dim or params.pop("dimension", None)
        if dim is None:
            dim, why = infer_dimension(contents)
        else:
            why = f"dimension {dim} (given)"
        params.pop("dimension", None)
        print(why)
        settings = settings_for(dim, params)
        targets = None
        if args.targets:
            table = read_targets(args.targets, dim)
            targets = Targets(table.ids, table.working, table.destination, str(args.targets))
            if contents.targets:
                print(f"targets from {args.targets} (the bag's targets topic is ignored)")
        if args.loo:
            print("leave-one-out: one model rebuild per fiducial ...", flush=True)
        ev = evaluate_contents(contents, settings, targets, loo=args.loo)
    except KeyboardInterrupt:
        print("evaluate: interrupted", file=sys.stderr)
        return 130
    print_summary(ev)
    if args.json:
        write_json(ev.report, args.json)
        print(f"wrote {args.json}")
    if args.out:
        paths = write_report_dir(ev, args.out, f"Evaluation of {args.bag.name}")
        print(f"wrote {len(paths)} files to {args.out}/ (report.md, report.json, figures)")
    return 0


# -- replay ------------------------------------------------------------------------------------
def replay(args: argparse.Namespace) -> int:
    """``replay``: publish the bag with its timing scaled by ``--rate``."""
    try:
        from .replay import replay as run

        result = run(args.bag, rate=args.rate, loop=args.loop, topics=args.topics,
                     wait=args.wait, progress=not args.quiet)
    except KeyboardInterrupt:
        print("replay: interrupted", file=sys.stderr)
        return 130
    except ImportError as exc:
        raise ValueError(f"{exc}: rclpy or a message package is missing; run "
                         "scripts/bootstrap.sh and source scripts/env.sh") from None
    print(f"replay: published {result.published} message(s) on {result.topics} topic(s) in "
          f"{result.seconds:.2f} s")
    return 0


# -- synth-bag ---------------------------------------------------------------------------------
def cell_messages(cell: Any, topics: Topics = DEFAULT_TOPICS, working_frame: str = "tracker",
                  destination_frame: str = "world", period_s: float = 0.02,
                  points: bool = False, start_ns: int = SYNTH_START_NS) -> Iterator[OutMessage]:
    """The messages of a synthetic cell (mm) as recorded from a robot visiting the holes, in
    metres: every fiducial once, then the repeated ones again, pass by pass; then the targets
    (with truth) the same way. Stamps ``period_s`` apart; 2D cells get z = 0.

    :param points: fiducials as a working and a destination ``PointStamped`` with one stamp
        (ids then assigned by the node's proximity rule) instead of ``FiducialPair``.
    """
    step = int(round(period_s * 1e9))
    k = 0

    def xyz(p: np.ndarray) -> tuple[float, float, float]:
        v = np.asarray(p, dtype=float) * MM_TO_M
        return (float(v[0]), float(v[1]), float(v[2]) if len(v) > 2 else 0.0)

    def passes(groups):
        for r in range(max(len(g) for g in groups)):
            for j, g in enumerate(groups):
                if r < len(g):
                    yield j, g[r]

    for j, w in passes(cell.fiducial_measurements):
        stamp = start_ns + k * step
        d = xyz(cell.fiducial_truth[j])
        if points:
            yield OutMessage(topics.working_point, "point", stamp, working_frame, xyz(w))
            yield OutMessage(topics.destination_point, "point", stamp, destination_frame, d)
        else:
            yield OutMessage(topics.fiducial_pairs, "pair", stamp, working_frame, xyz(w),
                             cell.fiducial_ids[j], destination_frame, d)
        k += 1
    for j, w in passes(cell.target_measurements):
        yield OutMessage(topics.targets, "pair", start_ns + k * step, working_frame, xyz(w),
                         cell.target_ids[j], destination_frame, xyz(cell.target_truth[j]))
        k += 1


def synth_bag(args: argparse.Namespace) -> int:
    """``synth-bag``: write a synthetic cell as a bag."""
    from .core.synthetic import make_cell
    from .io.bag import write_bag

    cell = make_cell(args.cell, seed=args.seed, repeats=args.repeats)
    topics = Topics.for_node(args.node_name)
    n_fid = sum(len(m) for m in cell.fiducial_measurements)
    n_tgt = sum(len(m) for m in cell.target_measurements)
    total = n_fid * (2 if args.points else 1) + n_tgt
    n = write_bag(args.out, cell_messages(cell, topics, args.working_frame,
                                          args.destination_frame, args.period, args.points),
                  args.storage, progress=not args.quiet, total=total)
    print(f"wrote {args.out} ({args.storage}): cell {args.cell} seed {args.seed}, "
          f"{len(cell.fiducial_ids)} fiducials ({n_fid} measurements"
          f"{' as point pairs' if args.points else ''}), {len(cell.target_ids)} targets "
          f"({n_tgt} measurements) on {topics.targets}; {n} messages, metres, "
          f"{cell.spec.dimension}D{' (z = 0)' if cell.spec.dimension == 2 else ''}")
    return 0
