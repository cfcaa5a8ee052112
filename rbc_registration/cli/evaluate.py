"""``rbc-registration evaluate``: a recorded bag through the node's pipeline, offline (no ROS
graph, no rclpy, no message packages), reported like ``register``. Lengths in metres (REP 103);
see docs/BAGS.md."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ..io.escape import terminal
from .options import (add_model_options, node_name, output_file, refuse_outputs_onto_inputs,
                      unit_mismatch_lines, warn)

#: The input topics that can be named, with what they carry.
TOPIC_OPTIONS = (("fiducial", "fiducial_pairs", "FiducialPair"),
                 ("working", "working_point", "PointStamped, working frame"),
                 ("destination", "destination_point", "PointStamped, destination frame"),
                 ("targets", "targets", "FiducialPair targets with truth"))


def add_parser(sub: Any) -> None:
    """Add ``evaluate`` to the subparsers of ``rbc-registration``."""
    ev = sub.add_parser("evaluate", help="evaluate a recorded bag offline, like register")
    ev.add_argument("bag", type=Path, help="rosbag2 directory, .mcap or .db3 file (metres)")
    ev.add_argument("--targets", type=Path, metavar="TARGETS.csv",
                    help="CSV in metres: id,wx,wy[,wz][,dx,dy[,dz]] (default: the targets topic)")
    ev.add_argument("--json", type=output_file, metavar="OUT.json", help="write the report as JSON")
    ev.add_argument("--out", type=Path, metavar="DIR",
                    help="write report.json, report.md and PNG figures here")
    add_model_options(ev, "default: 2 when every z of the measurements is 0, else 3", "m",
                      defaults=False)
    ev.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                    help="a registration_node parameter, e.g. -p merge_radius:=0.002 (repeatable)")
    ev.add_argument("--loo", action="store_true", help="leave-one-out estimate over fiducials")
    ev.add_argument("--node-name", type=node_name, default=None,
                    help="default topics are /NODE_NAME/fiducial_pairs etc. (default: the "
                         "namespace of the topics named with --*-topic when they share one, "
                         "else registration_node)")
    for option, _, what in TOPIC_OPTIONS:
        ev.add_argument(f"--{option}-topic", metavar="TOPIC", help=f"{what} topic")
    ev.add_argument("--quiet", action="store_true", help="no progress output")
    ev.set_defaults(func=run)


def topics_from_args(args: argparse.Namespace) -> tuple[Any, list[str]]:
    """The topics to read (``Topics``) and the ones named explicitly (which must exist)."""
    from ..io.bag.records import Topics

    named = {field: getattr(args, f"{option}_topic") for option, field, _ in TOPIC_OPTIONS}
    explicit = {k: v for k, v in named.items() if v}
    node = args.node_name
    if node is None:
        # --fiducial-topic /cell_a/reg/fiducial_pairs: the targets are /cell_a/reg/targets (the
        # node's own namespace), not /registration_node/targets, a topic such a bag lacks
        # (the root counts as a namespace: /tracker/point and /robot_point share none)
        parents = {t.rstrip("/").rpartition("/")[0] for t in explicit.values()}
        node = parents.pop() if len(parents) == 1 and "" not in parents else "registration_node"
    return Topics.for_node(node)._replace(**explicit), list(explicit.values())


def parse_params(items: list[str]) -> dict[str, Any]:
    """``NAME:=VALUE`` strings -> typed node parameters (type of the parameter's default).

    :raises ValueError: on a malformed item, an unknown name or a value of the wrong type.
    """
    from ..pipeline.settings import REMOVED, SPECS

    out: dict[str, Any] = {}
    for item in items:
        name, sep, text = item.partition(":=")
        name = name.strip()
        if not sep or not name:
            raise ValueError(f"-p expects NAME:=VALUE, got {item!r}")
        if name in REMOVED:
            raise ValueError(f"-p {name}: {REMOVED[name]}")
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


def run(args: argparse.Namespace) -> int:
    """Bag -> the node's accumulation and model -> report (stdout, JSON, directory)."""
    from ..io.bag.reader import read_bag
    from ..io.bag.records import PointMessage
    from ..io.csv_io import read_targets
    from ..io.evaluation import (REPORT_FILES, ambiguous_points_line, duplicates_line,
                                 evaluate_contents, print_summary, with_warnings,
                                 write_report_dir)
    from ..io.report import write_json
    from ..pipeline.offline import infer_dimension, settings_for
    from ..pipeline.targets import Targets

    inputs = [("bag", args.bag), ("--targets", args.targets)]
    refuse_outputs_onto_inputs([("--json", args.json), ("--out", args.out)], inputs,
                               REPORT_FILES, directories=("--out",))
    params = parse_params(args.param)
    for key, value in (("sigma", args.sigma), ("sigma_axis", args.sigma_axis),
                       ("decision", args.decision), ("restoration", args.restoration),
                       ("restoration_steps", args.steps), ("interpolation", args.interpolation)):
        if value is not None:
            params[key] = value
    topics, required = topics_from_args(args)
    try:
        contents = read_bag(args.bag, topics, required, progress=not args.quiet)
        dim = args.dim or params.pop("dimension", None)
        if dim is None:
            dim, why = infer_dimension(contents.inputs, contents.targets,
                                       params.get("working_frame", ""),
                                       params.get("destination_frame", ""))
        else:
            why = f"dimension {dim} (given)"
        params.pop("dimension", None)
        print(why)
        settings = settings_for(dim, params)
        targets = None
        if args.targets:
            # Repeats of one id are checked as the bag's recorded targets are: the node's
            # outlier_distance (metres), so a one-id file is checked too; a session column is
            # mapped by the fiducials' sessions (read once they are known).
            def targets(plan: Any, path: Path = args.targets) -> Targets:
                table = read_targets(path, dim, settings.outlier_distance, sessions=plan)
                return Targets(table.ids, table.working, table.destination, str(path))

            if contents.targets:
                print(f"targets from {terminal(args.targets)} (the bag's targets topic is ignored)")
        if args.loo:
            print("leave-one-out: one model rebuild per fiducial ...", flush=True)
        ev = evaluate_contents(contents, settings, targets, loo=args.loo)
    except KeyboardInterrupt:
        print("evaluate: interrupted", file=sys.stderr)
        return 130
    print_summary(ev)
    from ..core.rigid.scale import implausible_metres
    large = implausible_metres(ev.model.destination)
    ambiguous = ambiguous_points_line(ev, topics.working_point, topics.destination_point)
    # Every warning goes to stderr and into report.json / report.md (the blunder line is the
    # model state's, ev.warnings already).
    sample = ("point_mode 'sample': a bag does not record the ~/take_sample calls, so evaluate "
              "pairs the working and destination points by their stamps (point_mode 'pair')") \
        if settings.point_mode == "sample" and any(isinstance(m, PointMessage)
                                                   for m in contents.inputs) else ""
    duplicates = duplicates_line(ev, f"bag {contents.path}")
    ev = with_warnings(ev, [w for w in (duplicates, sample, ambiguous, large) if w]
                       + unit_mismatch_lines(
                           ev.model.working,
                           ev.targets.working if ev.targets is not None else None, ev.report,
                           ev.model.destination,
                           ev.targets.destination if ev.targets is not None else None))
    for line in ev.warnings:
        warn("evaluate", line)
    if args.json:
        write_json(ev.report, args.json)
        print(f"wrote {terminal(args.json)}")
    if args.out:
        paths = write_report_dir(ev, args.out, f"Evaluation of {args.bag.name}")
        print(f"wrote {len(paths)} files to {terminal(args.out)}/ (report.md, report.json, "
              "figures)")
    return 0
