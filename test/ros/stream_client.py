"""A separate client process for the process tests and the demo: streams the fiducial pairs of a
cell (``.npz`` from ``ros_helpers.make_cell``) to ``/<node>/fiducial_pairs``, waits until the node
accepted them all, asks for a recompute, calls ``/<node>/correct_target`` for every target and
writes the answers as JSON.

    python stream_client.py NODE_NAME CELL.npz ANSWERS.json [--first K] [--start S]

DDS stays on loopback: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST is forced here as well.
"""

import argparse
import json
import os
import sys
import time

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_STATIC_PEERS", None)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from rbc_registration_interfaces.msg import FiducialPair, RegistrationStatus  # noqa: E402
from rbc_registration.ros.services import rebuild_requested_ns  # noqa: E402
from rbc_registration_interfaces.srv import CorrectTarget  # noqa: E402

from ros_helpers import answer_key, pair_msg, target_msg  # noqa: E402

TIMEOUT = 30.0


def call(node, client, request):
    assert client.wait_for_service(timeout_sec=TIMEOUT), f"{client.srv_name} not available"
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=TIMEOUT)
    assert future.done(), f"{client.srv_name} did not answer"
    return future.result()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("node_name")
    parser.add_argument("cell")
    parser.add_argument("answers")
    parser.add_argument("--start", type=int, default=0, help="first pair index to stream")
    args = parser.parse_args()
    data = np.load(args.cell)
    cell = {k: data[k] for k in data.files}
    rclpy.init()
    node = rclpy.create_node("stream_client")
    try:
        ns = f"/{args.node_name}"
        statuses = []
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        node.create_subscription(RegistrationStatus, f"{ns}/status", statuses.append, latched)
        pub = node.create_publisher(FiducialPair, f"{ns}/fiducial_pairs", 1000)
        end = time.monotonic() + TIMEOUT
        while pub.get_subscription_count() == 0 and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.05)
        n = len(cell["fid"])
        for k in range(args.start, n):
            pub.publish(pair_msg(cell, k, stamp_s=100.0 + k))
        while time.monotonic() < end and not (statuses and statuses[-1].n_measurements >= n):
            rclpy.spin_once(node, timeout_sec=0.05)
        assert statuses and statuses[-1].n_measurements == n, "node did not accept every pair"
        recompute = call(node, node.create_client(Trigger, f"{ns}/recompute"), Trigger.Request())
        assert recompute.success, recompute.message
        requested = rebuild_requested_ns(recompute.message)   # answered at once: wait for it
        while time.monotonic() < end and not (
                statuses[-1].last_recompute.sec * 10**9 + statuses[-1].last_recompute.nanosec
                >= requested):
            rclpy.spin_once(node, timeout_sec=0.05)
        client = node.create_client(CorrectTarget, f"{ns}/correct_target")
        answers = [answer_key(call(node, client, CorrectTarget.Request(target=target_msg(t))))
                   for t in cell["targets"]]
        with open(args.answers, "w") as f:
            json.dump(answers, f)
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
