"""The cost of one executor wake with nothing to do (``SingleThreadedExecutor.spin_once(0)``:
rclpy builds the wait set of every entity, waits 0 and checks each in Python), for the node and
for a bare rclpy node with one ``Trigger`` service (the floor of ``bench_node.py``), in process.
Every ``~/correct_target`` and every batch of input messages pays it once. Compare trees with
``PYTHONPATH=<tree>``, alternating.

    source scripts/env.sh && python benchmarks/bench_executor_wake.py
"""
import os
import tempfile
import time

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_STATIC_PEERS", None)
os.environ.setdefault("ROS_DOMAIN_ID", str(os.getpid() % 101 + 1))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
import rclpy  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

import rbc_registration  # noqa: E402
from rbc_registration.ros.node import RegistrationNode  # noqa: E402

WAKES, BLOCKS = 2000, 5


def wake_us(ctx: Context, node: Node) -> float:
    """The fastest of BLOCKS blocks of WAKES empty wakes [us per wake]."""
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    for _ in range(200):
        ex.spin_once(timeout_sec=0)
    best = []
    for _ in range(BLOCKS):
        t = time.perf_counter()
        for _ in range(WAKES):
            ex.spin_once(timeout_sec=0)
        best.append((time.perf_counter() - t) / WAKES * 1e6)
    ex.remove_node(node)
    ex.shutdown()
    return min(best)


def main() -> None:
    ctx = Context()
    rclpy.init(context=ctx)
    bare = Node("bare", context=ctx)
    bare.create_service(Trigger, "~/trigger", lambda request, response: response)
    node = RegistrationNode("wake", context=ctx, parameter_overrides=[
        Parameter("state_dir", value=tempfile.mkdtemp())])
    print(f"tree {os.path.dirname(os.path.dirname(rbc_registration.__file__))}; node: "
          f"{len(list(node.services))} services, {len(list(node.subscriptions))} subscriptions, "
          f"{len(list(node.timers))} timers, {len(list(node.waitables))} waitables; bare: "
          f"{len(list(bare.services))} services, {len(list(bare.waitables))} waitables")
    print(f"empty wake [us]: bare {wake_us(ctx, bare):.1f}, node {wake_us(ctx, node):.1f}")
    node.destroy_node()
    bare.destroy_node()
    rclpy.shutdown(context=ctx)


if __name__ == "__main__":
    main()
