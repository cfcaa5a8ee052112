"""Oversized ``~/correct_targets`` requests against another client's ``~/correct_target``.

A node process with the soak's cell (48 holes, 3 rounds); this process is the measuring client:
``~/correct_target`` one call after the other, ``--period`` s apart, its round trip recorded.
Three phases, each while the node's RSS (``/proc/<pid>/status``) is sampled:

1. ``alone``: nobody else calls.
2. ``oversized``: a client process sends one request of 1,000,000 targets and a second one
   sends 10 such requests back to back (what each got is printed: CorrectTargets holds at most
   100,000 targets, so each client's middleware refuses to send them).
3. ``busy processes``: the control of phase 2 without ROS: two processes that only burn CPU
   for 12 s each (an oversized client's own cost is converting its request, seconds of CPU
   on the same 2 cores as the node).
4. ``at the bound``: a client process sends 5 requests of 100,000 targets (the most
   CorrectTargets holds; more than ``max_targets`` 10,000, so the node refuses each after
   taking it in) back to back.

Prints per phase the p50 / p99 / max of the round trips, p99 against ``alone``, and the node's
RSS at the start and its largest sample during the phase.

    source scripts/env.sh && nice python benchmarks/bench_oversized.py
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_STATIC_PEERS", None)
os.environ.setdefault("ROS_DOMAIN_ID", str(os.getpid() % 101 + 1))

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from soak_procs import cell_truth, to_working  # noqa: E402  (the soak's cell)

#: The oversized clients (separate processes): ``python bench_oversized.py --client N COUNT``.
CLIENT = r"""
import json, sys, time
import rclpy
from geometry_msgs.msg import PointStamped
from rbc_registration_interfaces.srv import CorrectTargets
name, targets, count = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
rclpy.init()
node = rclpy.create_node("oversized_client")
client = node.create_client(CorrectTargets, f"/{name}/correct_targets")
assert client.wait_for_service(timeout_sec=60)
point = PointStamped()
point.header.frame_id = "tracker"
request = CorrectTargets.Request(targets=[point] * targets)
out = []
for _ in range(count):
    t0 = time.monotonic()
    try:
        future = client.call_async(request)
    except Exception as exc:
        out.append({"s": time.monotonic() - t0, "got": f"{type(exc).__name__}: {exc}"})
        continue
    rclpy.spin_until_future_complete(node, future, timeout_sec=120)
    r = future.result()
    out.append({"s": time.monotonic() - t0, "got": "no answer" if r is None else
                f"success={r.success}: {r.message}"})
print(json.dumps(out))
node.destroy_node()
rclpy.shutdown()
"""


#: Phase 3's processes.
BUSY = "import time\nend = time.monotonic() + 12\nwhile time.monotonic() < end:\n    pass\n"


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


class RssSampler:
    """The largest RSS of ``pid`` while running (sampled every 20 ms)."""

    def __init__(self, pid: int) -> None:
        self.pid, self.peak, self._stop = pid, 0.0, threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            self.peak = max(self.peak, rss_mb(self.pid))
            time.sleep(0.02)

    def stop(self) -> float:
        self._stop.set()
        self._thread.join()
        return self.peak


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--period", type=float, default=0.02, help="s between calls")
    parser.add_argument("--calls", type=int, default=500, help="calls of the alone phase")
    args = parser.parse_args()

    import rclpy
    from geometry_msgs.msg import Point
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from rbc_registration.ros.process import start_node, stop_process
    from rbc_registration_interfaces.msg import FiducialPair, RegistrationStatus
    from rbc_registration_interfaces.srv import CorrectTarget

    name = f"bench_oversized_{os.getpid()}"
    node_proc = start_node(name, {"state_dir": "''", "debounce_period": 0.05})
    rclpy.init()
    client_node = rclpy.create_node("bench_client")
    statuses: list = []
    client_node.create_subscription(
        RegistrationStatus, f"/{name}/status", statuses.append,
        QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.TRANSIENT_LOCAL))
    pub = client_node.create_publisher(FiducialPair, f"/{name}/fiducial_pairs", 1000)
    client = client_node.create_client(CorrectTarget, f"/{name}/correct_target")
    try:
        assert client.wait_for_service(timeout_sec=60), "the node did not come up"
        truth = cell_truth()
        working = to_working(truth)
        rng = np.random.default_rng(0)
        for _round in range(3):
            for k in rng.permutation(len(truth)):
                msg = FiducialPair()
                msg.header.frame_id, msg.destination_frame_id = "tracker", "world"
                msg.fiducial_id = f"H{k:02d}"
                w = working[k] + rng.normal(0, 5e-5, 3)
                msg.working_point = Point(x=float(w[0]), y=float(w[1]), z=float(w[2]))
                d = truth[k]
                msg.destination_point = Point(x=float(d[0]), y=float(d[1]), z=float(d[2]))
                pub.publish(msg)
        end = time.monotonic() + 60
        while not (statuses and statuses[-1].model_valid) and time.monotonic() < end:
            rclpy.spin_once(client_node, timeout_sec=0.05)
        assert statuses and statuses[-1].model_valid, "no model"
        request = CorrectTarget.Request()
        request.target.header.frame_id = "tracker"
        request.target.point.x, request.target.point.y, request.target.point.z = \
            (float(v) for v in working[5] + 0.01)

        def one_call() -> float:
            t0 = time.perf_counter()
            future = client.call_async(request)
            rclpy.spin_until_future_complete(client_node, future, timeout_sec=60)
            assert future.result() is not None and future.result().success
            return time.perf_counter() - t0

        for _ in range(50):
            one_call()             # warm up
        results = {}

        def phase(label: str, clients: list) -> None:
            rss0 = rss_mb(node_proc.pid)
            sampler = RssSampler(node_proc.pid)
            procs = [subprocess.Popen([sys.executable, "-c", CLIENT, name, str(n), str(c)]
                                      if n else [sys.executable, "-c", BUSY],
                                      stdout=subprocess.PIPE, text=True) for n, c in clients]
            times = []
            while (len(times) < args.calls if not procs
                   else any(p.poll() is None for p in procs)):
                times.append(one_call())
                time.sleep(args.period)
            outputs = [(n, c, json.loads(p.communicate()[0] or "[]"))
                       for (n, c), p in zip(clients, procs)]
            peak = sampler.stop()
            t = np.array(times) * 1e3
            results[label] = float(np.percentile(t, 99))
            print(f"{label}: {len(t)} calls, p50 {np.percentile(t, 50):.2f} ms, p99 "
                  f"{results[label]:.2f} ms ({results[label] / results['alone']:.2f}x alone), "
                  f"max {t.max():.2f} ms; node RSS {rss0:.1f} MB at the start, largest "
                  f"{peak:.1f} MB (+{peak - rss0:.1f} MB)")
            for n, c, out in outputs:
                if not n:
                    continue
                got = sorted({o["got"] for o in out})
                print(f"  client of {c} x {n:,} targets: {len(out)} answers, "
                      f"{max((o['s'] for o in out), default=0):.1f} s at most each: {got}")

        phase("alone", [])
        phase("oversized", [(1_000_000, 1), (1_000_000, 10)])
        phase("busy processes", [(0, 1), (0, 1)])
        phase("at the bound", [(100_000, 5)])
    finally:
        client_node.destroy_node()
        rclpy.shutdown()
        stop_process(node_proc)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
