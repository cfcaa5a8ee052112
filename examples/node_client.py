"""Drive a running ``registration_node`` from Python (rclpy): publish the fiducial pairs of a
FIDUCIALS.csv, wait for the model they make, correct the targets of a TARGETS.csv through
``~/correct_target`` and optionally ``~/save`` the calibration.

    python examples/node_client.py examples/cell3d/fiducials.csv \\
        --targets examples/cell3d/targets.csv --save
    python examples/node_client.py --targets examples/cell3d/targets.csv

Without FIDUCIALS.csv nothing is published: the targets are corrected by what the node holds
(a live model, or a calibration file it loaded).

The CSV files are in ``--unit`` (default mm); the node works in metres (REP 103), so points are
converted on the way in and answers on the way out. The frames are the node's defaults
(``tracker`` -> ``world``); ``--node`` names another node (e.g. ``/cell_a/registration_node``).
Prints one line per target: the point to use (``destination``), the method and the 95 % bound,
and the error against the file's truth columns when it has them. Exit 1 when the node does not
answer or refuses a target.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from typing import Any

import numpy as np

from rbc_registration.core.constants import METRES_PER_UNIT, length_unit
from rbc_registration.io.csv_io import read_fiducials, read_targets

WAIT_S = 60.0


def call(node: Any, client: Any, request: Any, timeout: float = WAIT_S) -> Any:
    """Call a service and spin until it answers; raises ``RuntimeError`` on a timeout."""
    import rclpy

    if not client.wait_for_service(timeout_sec=timeout):
        raise RuntimeError(f"service {client.srv_name} is not available")
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=timeout)
    if not future.done():
        raise RuntimeError(f"service {client.srv_name} did not answer within {timeout} s")
    return future.result()


def pair_messages(path: str, scale: float, dim: int | None = None) -> list[Any]:
    """One ``FiducialPair`` per row of FIDUCIALS.csv (repeats included), in metres."""
    from geometry_msgs.msg import Point
    from rbc_registration_interfaces.msg import FiducialPair

    data = read_fiducials(path, dim=dim)
    messages = []
    for fid, working, destination in zip(data.ids, data.working_repeats,
                                         data.destination_repeats):
        destination = np.broadcast_to(destination, np.shape(working))
        for w, d in zip(np.atleast_2d(working), np.atleast_2d(destination)):
            w, d = np.resize(w * scale, 3) * (np.arange(3) < len(w)), \
                np.resize(d * scale, 3) * (np.arange(3) < len(d))
            messages.append(FiducialPair(
                fiducial_id=fid, working_point=Point(x=w[0], y=w[1], z=w[2]),
                destination_point=Point(x=d[0], y=d[1], z=d[2])))
    return messages


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("fiducials", nargs="?",
                        help="FIDUCIALS.csv: the pairs to publish (default: none)")
    parser.add_argument("--targets", help="TARGETS.csv: the targets to correct")
    parser.add_argument("--unit", default="mm", help="length unit of the files (default mm)")
    parser.add_argument("--node", default="/registration_node", help="the node's name")
    parser.add_argument("--save", action="store_true", help="call ~/save at the end")
    args = parser.parse_args(argv)
    scale = METRES_PER_UNIT[length_unit(args.unit)]

    import rclpy
    from geometry_msgs.msg import PointStamped
    from rbc_registration_interfaces.msg import FiducialPair, RegistrationStatus
    from rbc_registration_interfaces.srv import CorrectTarget
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_srvs.srv import Trigger

    pairs = pair_messages(args.fiducials, scale) if args.fiducials else []
    rclpy.init()
    node = rclpy.create_node("node_client_example")
    try:
        status: list[Any] = []
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(RegistrationStatus, f"{args.node}/status", status.append, latched)
        publisher = node.create_publisher(FiducialPair, f"{args.node}/fiducial_pairs",
                                          QoSProfile(depth=max(1, len(pairs)),
                                                     reliability=ReliabilityPolicy.RELIABLE))
        deadline = time.monotonic() + WAIT_S
        while (pairs and publisher.get_subscription_count() == 0) or not status:
            if time.monotonic() > deadline:
                raise RuntimeError(f"no node {args.node} (its ~/status and ~/fiducial_pairs)")
            rclpy.spin_once(node, timeout_sec=0.1)
        before = status[-1].n_measurements + status[-1].n_rejected
        for msg in pairs:
            msg.header.stamp = node.get_clock().now().to_msg()
            publisher.publish(msg)
        if pairs:
            print(f"published {len(pairs)} fiducial pairs to {args.node}/fiducial_pairs")
        while pairs and not (status[-1].n_measurements + status[-1].n_rejected
                             >= before + len(pairs)
                             and status[-1].n_pending == 0 and status[-1].model_valid):
            if time.monotonic() > deadline:
                raise RuntimeError("the node built no model of the pairs within "
                                   f"{WAIT_S} s (~/status: {status[-1].message!r})")
            rclpy.spin_once(node, timeout_sec=0.1)
        s = status[-1]
        if s.model_valid:
            print(f"model: {s.n_fiducials} fiducials, decision {s.decision_mode} -> "
                  f"{s.decision_method}, expected TRE {s.expected_tre_median / scale:.4g} "
                  f"{args.unit}")

        if args.targets:
            targets = read_targets(args.targets, s.dimension)
            correct = node.create_client(CorrectTarget, f"{args.node}/correct_target")
            for k, tid in enumerate(targets.ids):
                point = np.resize(targets.working[k] * scale, 3) * (np.arange(3) < s.dimension)
                request = CorrectTarget.Request()
                request.target = PointStamped()
                request.target.point.x, request.target.point.y, request.target.point.z = (
                    float(v) for v in point)
                answer = call(node, correct, request)
                if not answer.success:
                    print(f"{tid}: refused: {answer.message}", file=sys.stderr)
                    return 1
                p = answer.destination.point
                to_use = np.array([p.x, p.y, p.z])[:s.dimension] / scale
                line = (f"{tid}: destination {np.array2string(to_use, precision=4)} {args.unit}"
                        f" ({answer.method}, 95 % bound {answer.tre_bound / scale:.3g})")
                if targets.destination is not None:
                    error = np.linalg.norm(to_use - targets.destination[k])
                    line += f", error against the file's truth {error:.3g}"
                print(line)
        if args.save:
            answer = call(node, node.create_client(Trigger, f"{args.node}/save"),
                          Trigger.Request())
            print(answer.message if answer.success else f"save refused: {answer.message}")
            if not answer.success:
                return 1
        return 0
    except RuntimeError as error:
        print(f"node_client: {error}", file=sys.stderr)
        return 1
    finally:
        node.destroy_node()
        rclpy.shutdown()


if __name__ == "__main__":
    try:
        status = main()
        sys.stdout.flush()
    except BrokenPipeError:       # `... | head`: end quietly, as Unix tools do (128 + SIGPIPE)
        sys.stdout = open(os.devnull, "w")
        status = 141
    raise SystemExit(status)
