"""Benchmark of registration_node from a separate process, each figure against a bare rclpy floor
measured in the same run, in alternating blocks.

Three child processes: ``registration_node`` (journal on, flushed per record,
``debounce_period`` 0.2 s, ``status_period`` 0.05 s) and two *floors* (this script with
``--floor KIND``): bare nodes on the same executor type (``SingleThreadedExecutor``), each with a
subscriber of ``FiducialPair`` with the node's input QoS that only counts, publishing its count on
``~/status`` every 0.05 s like the node, and one server that only answers: the issue's floor a
``std_srvs/Trigger`` server, the *same-message floor* a ``CorrectTarget`` server returning one
prepared response shaped like the node's (frames, method, a message of the same length). The
second separates what rclpy and DDS cost for the larger ``CorrectTarget`` messages from the
node's own work; its subscriber also takes the queued pairs in batches as the node does
(``input_batch`` at its default, ``ros/batching.py``), so it is the same-take floor for ingestion.

Per run, alternating the order of the processes:

1. round trip: ``--calls`` sequential calls of ``~/correct_target`` (48-fiducial 3D model), of
   the floor's ``~/trigger`` and of the same-message floor's ``~/correct_target`` -> p50 / p99
   [ms]; ratio = node p50 / floor p50 (target <= 1.5), and node p50 / same-message floor p50;
2. ingestion: ``--pairs`` FiducialPair messages (repeated visits of the 48 holes without ids,
   merged by proximity) with at most ``WINDOW`` in flight, until ``~/status`` reports them all
   -> pairs/s; ratio = node / floor (target >= 0.8), and node / same-message floor (the
   counting subscriber taking up to ``input_batch`` queued pairs per wake-up like the node).

``--during-rebuild J`` measures instead ``~/correct_target`` latency while the node rebuilds a
``kriging`` model of J fiducials (3D), triggered by setting the ``interpolation`` parameter, and
how long the rebuild takes meanwhile: calls back to back (the most load one client can put on the
node), or ``--rate HZ`` calls per second (a cell asking for corrections at a steady rate).

Run (from the repository root, after scripts/bootstrap.sh):

    source scripts/env.sh && python benchmarks/bench_node.py              # --runs 5
    source scripts/env.sh && python benchmarks/bench_node.py --during-rebuild 5000
    source scripts/env.sh && python benchmarks/bench_node.py --during-rebuild 5000 --rate 100

DDS stays on loopback: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST is set here and inherited by the
children; ROS_DOMAIN_ID is this process's own unless set. Every loop is bounded in count and time.
"""

import argparse
import os
import statistics
import sys
import tempfile
import time

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_STATIC_PEERS", None)
os.environ.pop("ROS_LOCALHOST_ONLY", None)
os.environ.setdefault("ROS_DOMAIN_ID", str(os.getpid() % 101 + 1))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "test", "ros"))

import numpy as np  # noqa: E402
import rclpy  # noqa: E402
from rclpy._rclpy_pybind11 import RCLError  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile,  # noqa: E402
                       ReliabilityPolicy)
from std_srvs.srv import Trigger  # noqa: E402

from rbc_registration_interfaces.msg import FiducialPair, RegistrationStatus  # noqa: E402
from rbc_registration_interfaces.srv import CorrectTarget  # noqa: E402

from ros_helpers import make_cell, pair_msg, target_msg  # noqa: E402  (the tests' synthetic cell)

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
WINDOW = 2000  # pairs published but not yet reported accepted
STREAM = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_ALL,
                    reliability=ReliabilityPolicy.RELIABLE)
STATUS_PERIOD = 0.05
TARGETS = {"round_trip_ratio_max": 1.5, "ingestion_ratio_min": 0.8}


# -- the floor process ------------------------------------------------------------------------
def floor_answer() -> CorrectTarget.Response:
    """A ``CorrectTarget`` answer shaped like the node's (what the same-message floor returns)."""
    response = CorrectTarget.Response(success=True, method="paper", correction_applied=True,
                                      inside_hull=True, expected_error=float("nan"),
                                      expected_tre=1e-5, tre_bound=3e-5)
    response.message = ("paper: corrections applied (decision cv); cross-validated median "
                        "error 0.012 mm against 0.034 mm uncorrected")
    for point in (response.destination, response.corrected, response.uncorrected):
        point.header.frame_id = "world"
        point.point.x, point.point.y, point.point.z = 0.1, 0.2, 0.3
    return response


def run_floor(kind: str, ros_args: list[str]) -> int:
    """A bare node: one server (``kind`` "trigger": ``~/trigger``; "correct_target": a
    ``~/correct_target`` answering :func:`floor_answer`) + counting subscriber (the node's input
    QoS), one executor; ``ros_args`` (``--ros-args -r __node:=NAME``) name it."""
    from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
    from rclpy.executors import ExternalShutdownException

    from rbc_registration.pipeline.settings import SPECS
    from rbc_registration.ros.batching import batched_subscription
    from rbc_registration.ros.node import INPUT

    rclpy.init(args=[sys.argv[0], *ros_args])
    node = rclpy.create_node("bench_floor")
    count = [0]

    def on_pair(msg: FiducialPair) -> None:
        count[0] += 1

    def on_trigger(request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success = True
        return response

    pub = node.create_publisher(RegistrationStatus, "~/status", LATCHED)

    def publish_status() -> None:
        pub.publish(RegistrationStatus(n_measurements=count[0]))

    if kind == "trigger":   # the floor: rclpy's one message per wake-up
        node.create_subscription(FiducialPair, "~/fiducial_pairs", on_pair, INPUT["reliable"],
                                 callback_group=MutuallyExclusiveCallbackGroup())
    else:                   # the same-take floor: queued pairs in batches, as the node takes them
        batch = SPECS["input_batch"].default
        batched_subscription(node, FiducialPair, "~/fiducial_pairs", on_pair, INPUT["reliable"],
                             MutuallyExclusiveCallbackGroup(), lambda: batch)
    answer = floor_answer()

    def on_correct_target(request: CorrectTarget.Request,
                          response: CorrectTarget.Response) -> CorrectTarget.Response:
        return answer

    if kind == "trigger":
        node.create_service(Trigger, "~/trigger", on_trigger,
                            callback_group=ReentrantCallbackGroup())
    else:
        node.create_service(CorrectTarget, "~/correct_target", on_correct_target,
                            callback_group=ReentrantCallbackGroup())
    node.create_timer(STATUS_PERIOD, publish_status,
                      callback_group=MutuallyExclusiveCallbackGroup())
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


# -- the client side --------------------------------------------------------------------------
def call(executor, client, request, timeout=30.0):
    future = client.call_async(request)
    executor.spin_until_future_complete(future, timeout_sec=timeout)
    if not future.done():
        raise RuntimeError(f"{client.srv_name} did not answer within {timeout} s")
    return future.result()


def spin_until(executor, predicate, timeout, what):
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            raise RuntimeError(f"timed out waiting for {what}")
        executor.spin_once(timeout_sec=0.01)


class Target:
    """One process under test: its status, its pair publisher and its round-trip request."""

    def __init__(self, client, executor, label: str, name: str, srv_type, srv: str) -> None:
        self.label, self.name, self.executor = label, name, executor
        self.statuses: list = []
        client.create_subscription(RegistrationStatus, f"/{name}/status", self.statuses.append,
                                   LATCHED)
        self.pub = client.create_publisher(FiducialPair, f"/{name}/fiducial_pairs", STREAM)
        self.srv = client.create_client(srv_type, f"/{name}/{srv}")
        self.requests: list = []

    def wait_ready(self) -> None:
        spin_until(self.executor, lambda: self.pub.get_subscription_count() > 0
                   and self.statuses, 60, f"the {self.label}")
        if not self.srv.wait_for_service(timeout_sec=60):
            raise RuntimeError(f"the {self.label}'s service is not available")

    @property
    def count(self) -> int:
        return self.statuses[-1].n_measurements

    def idle(self) -> None:
        """Wait until the node's model covers every accepted pair (no rebuild pending)."""
        spin_until(self.executor, lambda: self.statuses[-1].n_pending == 0, 120,
                   f"the {self.label} to finish rebuilding")

    def round_trip(self, calls: int) -> np.ndarray:
        self.idle()
        for k in range(50):  # warm-up
            call(self.executor, self.srv, self.requests[k % len(self.requests)])
        latencies = np.empty(calls)
        for k in range(calls):
            t0 = time.perf_counter()
            response = call(self.executor, self.srv, self.requests[k % len(self.requests)])
            latencies[k] = time.perf_counter() - t0
            if not response.success:
                raise RuntimeError(f"{self.label}: {response.message}")
        return latencies * 1e3

    def ingest(self, msgs: list) -> float:
        """Publish ``msgs`` (flow-controlled) and return pairs/s until all are reported."""
        self.idle()
        base = self.count
        t0 = time.perf_counter()
        for k, msg in enumerate(msgs):
            # Application-level flow control: at most WINDOW pairs in flight, so DDS histories
            # never fill up (a full KEEP_ALL writer stalls on the reliable protocol's timers
            # and would measure those, not the node).
            if k % 100 == 0:
                floor = base + k - WINDOW
                spin_until(self.executor, lambda f=floor: self.count >= f, 120,
                           f"the {self.label} to catch up")
            for _ in range(10000):
                try:
                    self.pub.publish(msg)
                    break
                except RCLError:  # writer full: the receiver is behind; wait, retry
                    self.executor.spin_once(timeout_sec=0.001)
        spin_until(self.executor, lambda: self.count >= base + len(msgs), 300,
                   f"all pairs counted by the {self.label}")
        return len(msgs) / (time.perf_counter() - t0)


def start_processes(state_dir: str, node_params: dict, floors: bool = True
                    ) -> tuple[list, dict]:
    """The node and (``floors``) the two floors; returns the processes and {label: node name}."""
    from rbc_registration.ros.process import start_node

    pid = os.getpid()
    names = {"node": f"bench_registration_{pid}", "floor": f"bench_floor_{pid}",
             "same-message floor": f"bench_floor_ct_{pid}"}
    params = {"debounce_period": 0.2, "status_period": STATUS_PERIOD, "state_dir": state_dir,
              "outlier_distance": 0.0, **node_params}
    me = [sys.executable, os.path.abspath(__file__), "--floor"]
    procs = [start_node(names["node"], params, ros_args=["--log-level", "warn"])]
    if floors:
        procs += [start_node(names["floor"], command=[*me, "trigger"]),
                  start_node(names["same-message floor"], command=[*me, "correct_target"])]
    return procs, names


def summary(values: list[float]) -> str:
    return f"min {min(values):.3g}, median {statistics.median(values):.3g}"


def bench_ratios(args, executor, node: Target, floor: Target, same: Target) -> None:
    cell = make_cell(seed=0, repeats=3)
    for k in range(len(cell["fid"])):
        node.pub.publish(pair_msg(cell, k, stamp_s=1.0 + k * 1e-3))
    spin_until(executor, lambda: node.count == len(cell["fid"]) and node.statuses[-1].model_valid
               and node.statuses[-1].n_pending == 0, 60, "the node's model")
    node.requests = [CorrectTarget.Request(target=target_msg(t)) for t in cell["targets"]]
    same.requests = node.requests
    floor.requests = [Trigger.Request()]
    big = make_cell(seed=1, repeats=args.pairs // 48 + 1)
    rows = []
    for run in range(args.runs):
        # new stamps every run: the same message again is a duplicate, rejected (not ingestion)
        msgs = [pair_msg(big, k, with_id=False, stamp_s=10.0 + run * 100.0 + k * 1e-4)
                for k in range(args.pairs)]
        order = [(node, floor, same), (floor, same, node), (same, node, floor)][run % 3]
        lat = {t.label: t.round_trip(args.calls) for t in order}
        rate = {t.label: t.ingest(msgs) for t in order}
        p50 = {k: float(np.percentile(v, 50)) for k, v in lat.items()}
        p99 = {k: float(np.percentile(v, 99)) for k, v in lat.items()}
        row = (p50["node"], p99["node"], p50["floor"], p99["floor"], p50["node"] / p50["floor"],
               rate["node"], rate["floor"], rate["node"] / rate["floor"],
               p50[same.label], p50["node"] / p50[same.label],
               rate[same.label], rate["node"] / rate[same.label])
        rows.append(row)
        print(f"run {run + 1} ({order[0].label} first): round trip p50 node {row[0]:.3f} ms "
              f"(p99 {row[1]:.3f}) / floor {row[2]:.3f} ms (p99 {row[3]:.3f}) = {row[4]:.2f}x, "
              f"/ same-message floor {row[8]:.3f} ms = {row[9]:.2f}x; "
              f"ingestion node {row[5]:.0f}/s / floor {row[6]:.0f}/s = {row[7]:.2f}x, "
              f"/ same-take floor {row[10]:.0f}/s = {row[11]:.2f}x",
              flush=True)
    cols = list(zip(*rows))
    print(f"\n{args.runs} runs, {args.calls} calls and {args.pairs} pairs per block; "
          f"load average {os.getloadavg()[0]:.2f} (1 min) at the end")
    print("| what | node | floor | ratio (node / floor) | target |")
    print("| --- | --- | --- | --- | --- |")
    print(f"| `~/correct_target` round trip p50 [ms] | {summary(cols[0])} | {summary(cols[2])} "
          f"| {summary(cols[4])} | <= {TARGETS['round_trip_ratio_max']} |")
    print(f"| round trip p99 [ms] | {summary(cols[1])} | {summary(cols[3])} | | |")
    print(f"| round trip p50 against the same-message floor [ms] | {summary(cols[0])} "
          f"| {summary(cols[8])} | {summary(cols[9])} | |")
    print(f"| ingestion [pairs/s] | {summary(cols[5])} | {summary(cols[6])} | {summary(cols[7])} "
          f"| >= {TARGETS['ingestion_ratio_min']} |")
    print(f"| ingestion against the same-take floor (batches of input_batch) [pairs/s] "
          f"| {summary(cols[5])} | {summary(cols[10])} | {summary(cols[11])} | |")


def bench_during_rebuild(args, client, executor, node: Target) -> None:
    """correct_target latency while a kriging rebuild of J fiducials runs in the node."""
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    j = args.during_rebuild
    side = int(np.ceil(j ** (1 / 3)))
    grid = np.array([[x, y, z] for x in range(side) for y in range(side)
                     for z in range(side)][:j], dtype=np.float64) * 0.05
    rng = np.random.default_rng(0)
    working = grid + 1e-4 * np.sin(grid * 3.0) + rng.normal(0, 1e-5, grid.shape)
    cell = {"ids": np.array([f"h{k}" for k in range(j)]), "fid": np.arange(j),
            "working": working, "destination": grid}
    node.requests = [CorrectTarget.Request(target=target_msg(grid[k] + 0.02))
                     for k in range(0, j, max(1, j // 50))]
    t0 = time.perf_counter()
    for k in range(j):
        if k % 100 == 0:
            spin_until(executor, lambda f=k - WINDOW: node.count >= f, 120, "the node")
        node.pub.publish(pair_msg(cell, k, stamp_s=1.0 + k * 1e-4))
    spin_until(executor, lambda: node.count >= j and node.statuses[-1].model_valid
               and node.statuses[-1].n_pending == 0, 600, "the paper model")
    print(f"J = {j}: published and built (paper) in {time.perf_counter() - t0:.1f} s")
    node.round_trip(200)
    base = node.round_trip(args.calls)
    print(f"idle: p50 {np.percentile(base, 50):.3f} ms, p99 {np.percentile(base, 99):.3f} ms, "
          f"max {base.max():.3f} ms")
    setp = client.create_client(SetParameters, f"/{node.name}/set_parameters")
    setp.wait_for_service(timeout_sec=30)
    stamp = node.statuses[-1].last_recompute
    kriging = ParameterValue(type=ParameterType.PARAMETER_STRING, string_value="kriging")
    request = SetParameters.Request(parameters=[Parameter(name="interpolation", value=kriging)])
    t_set = time.perf_counter()
    assert call(executor, setp, request).results[0].successful
    latencies = []
    deadline = t_set + args.rebuild_timeout
    period = 1.0 / args.rate if args.rate > 0 else 0.0
    t_next = t_set
    while node.statuses[-1].last_recompute == stamp and time.perf_counter() < deadline:
        if period:                        # paced: the next call at its slot, spinning meanwhile
            t_next += period
            while time.perf_counter() < t_next:
                executor.spin_once(timeout_sec=max(0.0, t_next - time.perf_counter()))
        t0 = time.perf_counter()
        response = call(executor, node.srv, node.requests[len(latencies) % len(node.requests)])
        latencies.append(time.perf_counter() - t0)
        assert response.success, response.message
    t_rebuild = time.perf_counter() - t_set
    done = node.statuses[-1].last_recompute != stamp
    ms = np.array(latencies) * 1e3
    pace = f"{args.rate:g} calls/s" if args.rate > 0 else "back to back"
    print(f"during the kriging rebuild ({'finished' if done else 'NOT finished'} after "
          f"{t_rebuild:.1f} s, incl. debounce 0.2 s): {len(ms)} calls {pace}, p50 "
          f"{np.percentile(ms, 50):.3f} ms, p99 {np.percentile(ms, 99):.3f} ms, "
          f"max {ms.max():.3f} ms; load average {os.getloadavg()[0]:.2f}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0], allow_abbrev=False)
    parser.add_argument("--runs", type=int, default=5, help="alternating runs")
    parser.add_argument("--calls", type=int, default=2000, help="round trips per block")
    parser.add_argument("--pairs", type=int, default=10000, help="pairs per ingestion block")
    parser.add_argument("--journal-fsync", action="store_true", help="fsync every record")
    parser.add_argument("--during-rebuild", type=int, default=0, metavar="J",
                        help="instead: correct_target latency during a kriging rebuild at J")
    parser.add_argument("--rate", type=float, default=0.0, metavar="HZ",
                        help="with --during-rebuild: calls per second (default 0: back to back)")
    parser.add_argument("--rebuild-timeout", type=float, default=120.0,
                        help="most seconds to wait for that rebuild")
    parser.add_argument("--floor", choices=("trigger", "correct_target"), help=argparse.SUPPRESS)
    args, rest = parser.parse_known_args()
    if args.floor:
        return run_floor(args.floor, rest)

    from rbc_registration.ros.process import stop_process

    state_dir = tempfile.mkdtemp(prefix="bench_node_")
    node_params = {"journal_fsync": "true" if args.journal_fsync else "false"}
    if args.during_rebuild:
        node_params.update(merge_radius=0.001, sigma=1e-5, debounce_period=0.2)
    procs, names = start_processes(state_dir, node_params, floors=not args.during_rebuild)
    rclpy.init()
    client = rclpy.create_node("bench_client")
    executor = SingleThreadedExecutor()
    executor.add_node(client)
    try:
        node = Target(client, executor, "node", names["node"], CorrectTarget, "correct_target")
        floor = Target(client, executor, "floor", names["floor"], Trigger, "trigger")
        same = Target(client, executor, "same-message floor", names["same-message floor"],
                      CorrectTarget, "correct_target")
        node.wait_ready()
        if args.during_rebuild:
            bench_during_rebuild(args, client, executor, node)
        else:
            floor.wait_ready()
            same.wait_ready()
            bench_ratios(args, executor, node, floor, same)
        return 0
    finally:
        executor.shutdown()
        client.destroy_node()
        rclpy.try_shutdown()
        for proc in procs:
            stop_process(proc)


if __name__ == "__main__":
    sys.exit(main())
