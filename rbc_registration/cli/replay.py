"""``rbc-registration replay``: publish a bag into the live ROS graph (rclpy is imported only
when it runs; see :mod:`rbc_registration.ros.replay`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from .options import name_list, positive


def add_parser(sub: Any) -> None:
    """Add ``replay`` to the subparsers of ``rbc-registration``."""
    rp = sub.add_parser("replay", help="publish a bag into the live ROS graph")
    rp.add_argument("bag", type=Path, help="rosbag2 directory, .mcap or .db3 file")
    rp.add_argument("--rate", type=positive, default=1.0,
                    help="time scale: 2 plays twice as fast (default 1)")
    rp.add_argument("--loop", action="store_true", help="play again and again until Ctrl-C")
    rp.add_argument("--topics", type=name_list("topics"), metavar="T1,T2",
                    help="only these topics (default: every topic)")
    rp.add_argument("--wait", type=float, default=5.0, metavar="SECONDS",
                    help="wait this long at most for subscribers before playing (default 5)")
    rp.add_argument("--quiet", action="store_true", help="no progress output")
    rp.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Publish the bag with its timing scaled by ``--rate``."""
    try:
        from ..ros.replay import replay

        result = replay(args.bag, rate=args.rate, loop=args.loop, topics=args.topics,
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
