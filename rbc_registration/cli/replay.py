"""``rbc-registration replay``: publish a bag into the live ROS graph (rclpy is imported only
when it runs; see :mod:`rbc_registration.ros.replay`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ..io.bag.records import DEFAULT_MAX_GAP, MAX_REPLAY_WAIT, REPLAY_RATES
from .options import name_list, number_in


def add_parser(sub: Any) -> None:
    """Add ``replay`` to the subparsers of ``rbc-registration``."""
    rp = sub.add_parser("replay", help="publish a bag into the live ROS graph")
    rp.add_argument("bag", type=Path, help="rosbag2 directory, .mcap or .db3 file")
    rp.add_argument("--rate", type=number_in(*REPLAY_RATES), default=1.0,
                    help=f"time scale: 2 plays twice as fast, {REPLAY_RATES[0]:g} to "
                         f"{REPLAY_RATES[1]:g} (default 1)")
    rp.add_argument("--loop", action="store_true", help="play again and again until Ctrl-C")
    rp.add_argument("--topics", type=name_list("topics"), metavar="T1,T2",
                    help="only these topics (default: every topic)")
    rp.add_argument("--wait", type=number_in(0.0, MAX_REPLAY_WAIT), default=5.0,
                    metavar="SECONDS", help="wait this long at most for subscribers before "
                                            f"playing, 0 to {MAX_REPLAY_WAIT:g} (default 5)")
    rp.add_argument("--max-gap", type=number_in(0.0, MAX_REPLAY_WAIT), default=DEFAULT_MAX_GAP,
                    metavar="SECONDS", help="longest pause between two messages (wall time, "
                    "after --rate): a longer gap in the receive times is shortened to it, with "
                    f"one line, 0 to {MAX_REPLAY_WAIT:g} (default {DEFAULT_MAX_GAP:g})")
    rp.add_argument("--quiet", action="store_true", help="no progress output")
    rp.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Publish the bag with its timing scaled by ``--rate``."""
    try:
        from ..ros.replay import replay

        result = replay(args.bag, rate=args.rate, loop=args.loop, topics=args.topics,
                        wait=args.wait, progress=not args.quiet, max_gap=args.max_gap)
    except KeyboardInterrupt:
        print("replay: interrupted", file=sys.stderr)
        return 130
    except ImportError as exc:
        raise ValueError(f"{exc}: rclpy or a message package is missing; run "
                         "scripts/bootstrap.sh and source scripts/env.sh") from None
    print(f"replay: published {result.published} message(s) on {result.topics} topic(s) in "
          f"{result.seconds:.2f} s")
    return 0
