"""A node restart on a long journal: time until the services are up and RSS, with and without
the checkpoint (pipeline/checkpoint.py), against the live node's RSS.

For each ``--pairs`` count, a journal of that many pairs of the soak's cell (48 holes, ids given,
in shuffled rounds) is written with the node's own ``Journal`` into a fresh ``state_dir``. Then:

1. ``first start``: the node starts on the journal alone (no checkpoint yet: it is replayed
   whole); once its model is built it writes the snapshot and the checkpoint; kill -9.
2. ``live``: started again (from the checkpoint), it takes ``--live`` more pairs over DDS, a
   ``~/recompute`` builds the model of every acknowledged pair, its answers to 20 targets and
   its RSS are recorded; kill -9.
3. ``restart``: started again; services up, RSS, the pairs back and the answers compared with
   the live node's (every field of ``~/correct_target``, exactly).

"services up": from the process start until ``~/correct_target`` first answers (asked every
50 ms; ``empty start``: the same for a node on an empty ``state_dir``); "model": until
``~/status`` says a model is served. RSS from ``/proc/<pid>/status`` once the model is served
(``VmRSS``; ``VmHWM`` is the peak).

    source scripts/env.sh && nice python benchmarks/bench_restart.py --pairs 100000 1000000

``--journal-only``: only the part of a restart that grows with the journal, in a fresh process:
``Journal.load_after`` at the journal's end (the CRC-32 pass, no tail), its time and RSS growth.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
import time

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_STATIC_PEERS", None)
os.environ.setdefault("ROS_DOMAIN_ID", str(os.getpid() % 101 + 1))

import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from soak_procs import cell_truth, to_working  # noqa: E402  (the soak's cell)

HEADER = {"working_frame": "tracker", "destination_frame": "world", "dimension": 3}


def write_journal(state_dir: str, pairs: int) -> float:
    """``pairs`` accepted measurements in ``state_dir``'s journal; returns its size [MB]."""
    from rbc_registration.core.measurements.accumulator import FiducialAccumulator
    from rbc_registration.pipeline.journal import Journal

    truth = cell_truth()
    working = to_working(truth)
    rng = np.random.default_rng(0)
    acc = FiducialAccumulator(3, "tracker", "world", 0.005)
    journal = Journal(state_dir, HEADER)
    journal.load()
    chunk, done = 10_000, 0
    while done < pairs:
        n = min(chunk, pairs - done)
        k = np.concatenate([rng.permutation(len(truth)) for _ in range(n // len(truth) + 1)])[:n]
        w = working[k] + rng.normal(0, 5e-5, (n, 3))
        d = truth[k] + rng.normal(0, 1e-5, (n, 3))
        journal.append_many(acc.prepare(f"H{j:02d}", w[i], d[i], stamp_s=1000.0 + done + i)
                            for i, j in enumerate(k))
        done += n
    journal.close()
    return os.path.getsize(journal.path) / 1e6


#: ``--journal-only``'s child: python -c LOAD_AFTER STATE_DIR OFFSET LINES RECORDS CRC.
LOAD_AFTER = r"""
import sys, time
from rbc_registration.pipeline.checkpoint import JournalPosition
from rbc_registration.pipeline.journal import Journal
def mb(key):
    return next(int(l.split()[1]) / 1024 for l in open("/proc/self/status") if l.startswith(key))
journal = Journal(sys.argv[1], {"working_frame": "tracker", "destination_frame": "world",
                                "dimension": 3})
before = mb("VmRSS")
t0 = time.perf_counter()
tail = journal.load_after(JournalPosition(*map(int, sys.argv[2:6]), 0))
took = time.perf_counter() - t0
assert tail is not None and tail[0] == [], journal.mismatch
print(f"{took:.3f} s, RSS {before:.0f} -> {mb('VmRSS'):.0f} MB (peak {mb('VmHWM'):.0f} MB)")
"""


def journal_only(pairs: int) -> None:
    """Write a journal of ``pairs`` pairs, then time ``load_after`` at its end in a child."""
    import subprocess
    import zlib

    work = tempfile.mkdtemp(prefix=f"bench_restart_{pairs}_")
    size = write_journal(work, pairs)
    crc = lines = 0
    with open(os.path.join(work, "journal.jsonl"), "rb") as f:
        while chunk := f.read(1 << 20):
            crc, lines = zlib.crc32(chunk, crc), lines + chunk.count(b"\n")
    offset = os.path.getsize(os.path.join(work, "journal.jsonl"))
    out = subprocess.run([sys.executable, "-c", LOAD_AFTER, work, str(offset), str(lines),
                          str(lines - 1), str(crc)], capture_output=True, text=True, check=True)
    print(f"{pairs:,} pairs ({size:.0f} MB): Journal.load_after at the end: {out.stdout.strip()}")


def proc_mb(pid: int, key: str) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


class Client:
    """This process's rclpy node talking to the node ``name``."""

    def __init__(self, name: str) -> None:
        import rclpy
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from std_srvs.srv import Trigger

        from rbc_registration_interfaces.msg import FiducialPair, RegistrationStatus
        from rbc_registration_interfaces.srv import CorrectTarget

        self.rclpy, self.name = rclpy, name
        self.node = rclpy.create_node("bench_restart_client")
        self.statuses: list = []
        self.node.create_subscription(
            RegistrationStatus, f"/{name}/status", self.statuses.append,
            QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.pub = self.node.create_publisher(FiducialPair, f"/{name}/fiducial_pairs", 1000)
        self.correct = self.node.create_client(CorrectTarget, f"/{name}/correct_target")
        self.recompute = self.node.create_client(Trigger, f"/{name}/recompute")
        self.CorrectTarget, self.Trigger, self.FiducialPair = CorrectTarget, Trigger, FiducialPair

    def spin_until(self, predicate, timeout: float, what: str) -> float:
        t0 = time.monotonic()
        while not predicate():
            if time.monotonic() - t0 > timeout:
                raise RuntimeError(f"timed out waiting for {what}")
            self.rclpy.spin_once(self.node, timeout_sec=0.01)
        return time.monotonic()

    def call(self, client, request):
        future = client.call_async(request)
        self.rclpy.spin_until_future_complete(self.node, future, timeout_sec=60)
        return future.result()

    def first_answer(self, timeout: float) -> float:
        """When ``~/correct_target`` first answers (any answer), asked every 50 ms: a killed
        node's service stays discovered for a while, so its discovery says nothing."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if not self.correct.service_is_ready():
                self.rclpy.spin_once(self.node, timeout_sec=0.01)
                continue
            future = self.correct.call_async(self.CorrectTarget.Request())
            self.rclpy.spin_until_future_complete(self.node, future, timeout_sec=0.05)
            if future.done():
                return time.monotonic()
            self.correct.remove_pending_request(future)
        raise RuntimeError("timed out waiting for the services")

    def answers(self, targets: np.ndarray) -> list:
        out = []
        for t in targets:
            request = self.CorrectTarget.Request()
            request.target.header.frame_id = "tracker"
            request.target.point.x, request.target.point.y, request.target.point.z = \
                (float(v) for v in t)
            r = self.call(self.correct, request)
            out.append((r.success, r.message, r.method, r.correction_applied, r.inside_hull,
                        *(getattr(p.point, a) for p in (r.destination, r.corrected,
                                                         r.uncorrected) for a in "xyz"),
                        r.correction.x, r.correction.y, r.correction.z,
                        repr(r.expected_error), repr(r.expected_tre), repr(r.tre_bound)))
        return out

    def destroy(self) -> None:
        self.node.destroy_node()


def start(client: Client, state_dir: str, log, n_expected: int, timeout: float = 300) -> dict:
    """Start the node, wait (at most ``timeout`` s) for its services and a model of
    ``n_expected`` measurements."""
    from rbc_registration.ros.process import start_node

    client.statuses.clear()
    t0 = time.monotonic()
    proc = start_node(client.name, {"state_dir": state_dir, "debounce_period": 0.05}, log=log)
    try:
        up = client.first_answer(timeout) - t0
        if n_expected == 0:
            return {"proc": proc, "up": up, "rss": proc_mb(proc.pid, "VmRSS")}
        model = client.spin_until(lambda: client.statuses and client.statuses[-1].model_valid
                                  and client.statuses[-1].n_measurements == n_expected,
                                  timeout, "the model") - t0
    except BaseException:
        proc.kill()           # no node outlives the benchmark
        proc.wait()
        raise
    return {"proc": proc, "up": up, "model": model, "rss": proc_mb(proc.pid, "VmRSS"),
            "hwm": proc_mb(proc.pid, "VmHWM"), "n": client.statuses[-1].n_measurements}


def kill(info: dict) -> None:
    info["proc"].send_signal(signal.SIGKILL)
    info["proc"].wait(timeout=30)


def bench(pairs: int, live_pairs: int) -> None:
    import rclpy
    from geometry_msgs.msg import Point

    from rbc_registration.pipeline.checkpoint import CHECKPOINT_NAME
    from rbc_registration.ros.services import rebuild_requested_ns

    work = tempfile.mkdtemp(prefix=f"bench_restart_{pairs}_")
    state_dir = os.path.join(work, "state")
    t0 = time.monotonic()
    size = write_journal(state_dir, pairs)
    print(f"{pairs:,} pairs: journal {size:.0f} MB written in {time.monotonic() - t0:.1f} s")
    client = Client(f"bench_restart_{os.getpid()}")
    log = open(os.path.join(work, "node.log"), "w")
    checkpoint = os.path.join(state_dir, CHECKPOINT_NAME)
    try:
        empty = start(client, os.path.join(work, "empty"), log, 0)
        kill(empty)
        first = start(client, state_dir, log, pairs, timeout=7200)   # a whole replay
        client.spin_until(lambda: os.path.exists(checkpoint), 120, "the checkpoint")
        kill(first)
        live = start(client, state_dir, log, pairs)
        truth = cell_truth()
        working = to_working(truth)
        rng = np.random.default_rng(1)
        for i in range(live_pairs):
            k = int(rng.integers(len(truth)))
            msg = client.FiducialPair()
            msg.header.frame_id, msg.destination_frame_id = "tracker", "world"
            msg.header.stamp.sec = 10_000_000 + i
            msg.fiducial_id = f"H{k:02d}"
            w, d = working[k] + rng.normal(0, 5e-5, 3), truth[k] + rng.normal(0, 1e-5, 3)
            msg.working_point = Point(x=float(w[0]), y=float(w[1]), z=float(w[2]))
            msg.destination_point = Point(x=float(d[0]), y=float(d[1]), z=float(d[2]))
            client.pub.publish(msg)
            if i % 100 == 99:
                rclpy.spin_once(client.node, timeout_sec=0.001)
        total = pairs + live_pairs
        client.spin_until(lambda: client.statuses and client.statuses[-1].n_measurements == total,
                          120, "the live pairs acknowledged")
        answer = client.call(client.recompute, client.Trigger.Request())
        asked = rebuild_requested_ns(answer.message)
        client.spin_until(lambda: client.statuses and client.statuses[-1].model_valid and (
            client.statuses[-1].last_recompute.sec * 10**9
            + client.statuses[-1].last_recompute.nanosec) >= asked, 120, "the rebuild")
        targets = working[:20] + 0.01
        live_answers = client.answers(targets)
        live_rss = proc_mb(live["proc"].pid, "VmRSS")
        kill(live)
        again = start(client, state_dir, log, total)
        same = client.answers(targets) == live_answers
        kill(again)
    finally:
        log.close()
        client.destroy()
    text = open(os.path.join(work, "node.log")).read()
    how = [line.split("restored ", 1)[1].split("; /tf_static")[0]
           for line in text.splitlines() if "restored " in line]
    print(f"  empty start (no journal): services up {empty['up']:.2f} s, RSS "
          f"{empty['rss']:.0f} MB")
    print(f"  first start (no checkpoint, whole replay): services up {first['up']:.2f} s, "
          f"model {first['model']:.2f} s, RSS {first['rss']:.0f} MB (peak {first['hwm']:.0f})")
    print(f"  live node ({live_pairs} more pairs over DDS, recomputed): RSS {live_rss:.0f} MB")
    print(f"  restart after kill -9: services up {again['up']:.2f} s, model "
          f"{again['model']:.2f} s, RSS {again['rss']:.0f} MB (peak {again['hwm']:.0f}), "
          f"{again['rss'] / live_rss:.2f}x live; {again['n']:,} of {total:,} pairs back; "
          f"answers {'identical to' if same else 'DIFFERENT from'} the live node's")
    print(f"  the starts' log: {how}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, nargs="+", default=[100_000, 1_000_000])
    parser.add_argument("--live", type=int, default=2000, help="pairs the live node takes")
    parser.add_argument("--journal-only", action="store_true",
                        help="only Journal.load_after on each journal (module docstring)")
    args = parser.parse_args()
    if args.journal_only:
        for pairs in args.pairs:
            journal_only(pairs)
        return 0
    import rclpy

    rclpy.init()
    try:
        for pairs in args.pairs:
            bench(pairs, args.live)
    finally:
        rclpy.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
