"""Memory the node keeps per accepted measurement, in process: what the soak's RSS growth
should be if nothing leaks.

Two measurements on the soak's cell (48 holes, half with ids):

- default: the accumulator and one ``FiducialSet`` (what a model rebuild takes) after
  ``--count`` measurements, traced by tracemalloc.
- ``--node``: a ``RegistrationNode`` in this process (journal in a temporary ``state_dir``)
  takes ``--count`` ``FiducialPair`` messages through its subscription callback, with one model
  rebuild (by its own recompute thread) every 400 messages, as at 200 pairs/s with the 2 s
  longest debounce; prints Python-traced memory (tracemalloc) and RSS every tenth, and the
  source lines whose traced memory grew most. Without rclpy spinning: no DDS traffic at all.

    source scripts/env.sh && python benchmarks/bench_memory.py --count 120000
    source scripts/env.sh && python benchmarks/bench_memory.py --node --count 120000
"""

from __future__ import annotations

import argparse
import gc
import os
import sys
import tempfile
import time
import tracemalloc

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_STATIC_PEERS", None)
os.environ["ROS_DOMAIN_ID"] = str(os.getpid() % 101 + 1)

import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from rbc_registration.core.measurements.accumulator import FiducialAccumulator  # noqa: E402
from soak_procs import cell_truth, to_working  # noqa: E402  (the soak's cell)

REBUILD_EVERY = 400  # messages: 2 s at 200/s, the longest debounce (10 x 0.2 s)


def measurements(count: int):
    rng = np.random.default_rng(0)
    truth = cell_truth()
    k = rng.integers(0, len(truth), count)
    w = (to_working(truth)[k] + rng.normal(0, 5e-5, (count, 3))).tolist()
    d = (truth[k] + rng.normal(0, 1e-5, (count, 3))).tolist()
    return [f"H{j:02d}" if j % 2 == 0 else "" for j in k], w, d


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def accumulator_only(count: int) -> None:
    ids, w, d = measurements(count)
    gc.collect()
    tracemalloc.start()
    acc = FiducialAccumulator(3, "tracker", "world", 0.005, 0.01)
    base = tracemalloc.get_traced_memory()[0]
    for n in range(count):
        acc.add(ids[n], w[n], d[n], stamp_s=float(n))
    gc.collect()
    after_acc = tracemalloc.get_traced_memory()[0]
    fiducials = acc.fiducial_set()
    gc.collect()
    after_set = tracemalloc.get_traced_memory()[0]
    tracemalloc.stop()
    per_acc = (after_acc - base) / count
    per_set = (after_set - after_acc) / count
    print(f"{count} measurements of {len(fiducials.ids)} fiducials: accumulator "
          f"{(after_acc - base) / 2**20:.1f} MiB ({per_acc:.0f} bytes per measurement), "
          f"FiducialSet of the served model {(after_set - after_acc) / 2**20:.1f} MiB "
          f"({per_set:.0f} bytes per measurement); together {per_acc + per_set:.0f} bytes per "
          f"measurement, {(per_acc + per_set) * 200 * 3600 / 2**20:.0f} MiB per hour at 200/s")


def in_node(count: int) -> None:
    import rclpy

    from rbc_registration.ros.node import RegistrationNode
    from rbc_registration_interfaces.msg import FiducialPair

    ids, w, d = measurements(count)
    msgs = []
    start_s = int(time.time())
    for n in range(count):
        m = FiducialPair()
        m.header.frame_id, m.destination_frame_id, m.fiducial_id = "tracker", "world", ids[n]
        # one stamp per measurement (one stamp with other points of one id is a conflict)
        m.header.stamp.sec, m.header.stamp.nanosec = start_s + n // 1000, (n % 1000) * 1_000_000
        m.working_point.x, m.working_point.y, m.working_point.z = w[n]
        m.destination_point.x, m.destination_point.y, m.destination_point.z = d[n]
        msgs.append(m)
    del ids, w, d
    state_dir = tempfile.mkdtemp(prefix="bench_memory_")
    rclpy.init(args=["--ros-args", "-p", f"state_dir:={state_dir}", "-p",
                     "debounce_period:=60.0"])  # rebuilds only when requested below
    node = RegistrationNode(f"bench_memory_{os.getpid()}")
    try:
        worker = node._worker  # the node's own recompute thread (a benchmark may peek)
        gc.collect()
        tracemalloc.start(5)
        start = tracemalloc.take_snapshot()
        base_traced, base_rss = tracemalloc.get_traced_memory()[0], rss_mb()
        print("| accepted | traced by tracemalloc [MiB] | RSS [MiB] | traced B/meas. | "
              "RSS B/meas. |\n|---|---|---|---|---|")
        for n, msg in enumerate(msgs, 1):
            node._on_fiducial_pair(msg)
            if n % REBUILD_EVERY == 0:
                assert worker.wait(worker.request_now(), 60), "rebuild timed out"
            if n % (count // 10) == 0:
                gc.collect()
                traced = tracemalloc.get_traced_memory()[0] - base_traced
                rss = rss_mb() - base_rss
                print(f"| {n} | {traced / 2**20:.1f} | {rss:.1f} | {traced / n:.0f} | "
                      f"{rss * 2**20 / n:.0f} |", flush=True)
        assert node.status().n_measurements == count, node.status()
        end = tracemalloc.take_snapshot()
        print("\nlargest growth by source line (tracemalloc, 5 frames):")
        for stat in end.compare_to(start, "lineno")[:8]:
            print(f"  {stat.size_diff / 2**20:+.1f} MiB {stat.count_diff:+d} blocks  "
                  f"{stat.traceback[0]}")
    finally:
        tracemalloc.stop()
        node.destroy_node()
        rclpy.try_shutdown()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--count", type=int, default=120_000, help="measurements")
    parser.add_argument("--node", action="store_true", help="through a RegistrationNode")
    args = parser.parse_args()
    (in_node if args.node else accumulator_only)(args.count)


if __name__ == "__main__":
    main()
