"""The child processes of the soak (benchmarks/soak.py): one streamer and N clients.

    python soak_procs.py streamer NODE_NAME WORKDIR --rate 200 [--seed S]
    python soak_procs.py client NODE_NAME WORKDIR --index K [--think 0.01] [--timeout 5]

Each child sets up its rclpy node, waits until it sees the node, writes ``<role>.ready`` in
WORKDIR, then waits for ``go.json`` (written by soak.py: ``t0`` and ``t_end`` on the shared
CLOCK_MONOTONIC) and works until ``t_end``; it writes ``<role>.json`` with its raw results and
exits by itself (also when soak.py never says go: after ``READY_TIMEOUT``).

The cell (metres): a 4 x 4 x 3 grid of holes 0.3 m apart in the destination frame (world); the
working frame (tracker) is a rigid motion of it plus a smooth bias of ~1 mm. Every pair is one
visit of a hole in a shuffled round, with 50 um noise per axis in the working frame and 10 um in
the destination frame. Holes with an even index carry their id (``H07``), the others have an
empty id (the node assigns it by proximity).

DDS stays on loopback: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST is forced here as well.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import time

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_STATIC_PEERS", None)
os.environ.pop("ROS_LOCALHOST_ONLY", None)

import numpy as np  # noqa: E402

READY_TIMEOUT = 180.0   # s: give up when soak.py does not say go
DISCOVERY_TIMEOUT = 60.0
MODEL_TIMEOUT = 60.0
LATE_LIMIT = 10.0       # s: the streamer stops this long after the end even if behind schedule
NOISE_WORKING = 5e-5    # m per axis
NOISE_DESTINATION = 1e-5
WORKING_FRAME, DESTINATION_FRAME = "tracker", "world"


def cell_truth() -> np.ndarray:
    """The 48 holes in the destination frame (m)."""
    return np.array([[x, y, z] for x in range(4) for y in range(4) for z in range(3)],
                    dtype=np.float64) * 0.3


def to_working(points: np.ndarray) -> np.ndarray:
    """Destination -> working frame (rigid motion) plus a smooth ~1 mm bias."""
    angle = 0.4
    rot = np.array([[math.cos(angle), -math.sin(angle), 0.0],
                    [math.sin(angle), math.cos(angle), 0.0], [0.0, 0.0, 1.0]])
    w = (points - np.array([1.2, -0.4, 0.8])) @ rot
    field = np.column_stack([np.sin(2.0 * w[:, 0] + 1.0), np.cos(1.5 * w[:, 1]),
                             np.sin(w[:, 0] + w[:, 2])])
    return w + 1e-3 * field


def wait_go(workdir: str, role: str, spin) -> dict:
    """Write ``<role>.ready``, then wait for ``go.json`` (calling ``spin()`` meanwhile)."""
    with open(os.path.join(workdir, f"{role}.ready"), "w") as f:
        f.write(str(os.getpid()))
    path = os.path.join(workdir, "go.json")
    end = time.monotonic() + READY_TIMEOUT
    while not os.path.exists(path):
        if time.monotonic() > end:
            raise RuntimeError(f"{role}: no go.json after {READY_TIMEOUT} s")
        spin()
    time.sleep(0.05)  # written atomically (rename), but be safe on slow file systems
    with open(path) as f:
        return json.load(f)


def write_json(workdir: str, role: str, data: dict) -> None:
    tmp = os.path.join(workdir, f"{role}.json.tmp")
    with open(tmp, "w") as f:
        json.dump(data, f)
    os.replace(tmp, os.path.join(workdir, f"{role}.json"))


def streamer(args, node, executor) -> dict:
    from rclpy._rclpy_pybind11 import RCLError
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    from rbc_registration_interfaces.msg import FiducialPair

    qos = QoSProfile(depth=1000, history=HistoryPolicy.KEEP_ALL,
                     reliability=ReliabilityPolicy.RELIABLE)  # as the node's input
    pub = node.create_publisher(FiducialPair, f"/{args.node_name}/fiducial_pairs", qos)
    end = time.monotonic() + DISCOVERY_TIMEOUT
    while pub.get_subscription_count() == 0:
        if time.monotonic() > end:
            raise RuntimeError("streamer: the node's subscription did not appear")
        executor.spin_once(timeout_sec=0.05)
    go = wait_go(args.workdir, "streamer", lambda: time.sleep(0.02))
    rng = np.random.default_rng(args.seed)
    truth = cell_truth()
    working = to_working(truth)
    ids = [f"H{k:02d}" if k % 2 == 0 else "" for k in range(len(truth))]
    order: list[int] = []
    published = retries = 0
    lateness_max = 0.0
    late_over_10ms = 0
    t0, t_end = go["t0"], go["t_end"]
    period = 1.0 / args.rate
    msg = FiducialPair()
    msg.header.frame_id = WORKING_FRAME
    msg.destination_frame_id = DESTINATION_FRAME
    while True:
        due = t0 + published * period  # a fixed schedule: no drift, catch up when late
        now = time.monotonic()
        if due >= t_end or now > t_end + LATE_LIMIT:  # too far behind: stop, reported short
            break
        if args.max_pairs and published >= args.max_pairs:
            break  # a services-only run: the model is built, no further pairs
        if due > now:
            time.sleep(due - now)
        else:
            lateness_max = max(lateness_max, now - due)
            late_over_10ms += (now - due) > 0.01
        if not order:
            order = list(rng.permutation(len(truth)))
        k = order.pop()
        w = working[k] + rng.normal(0.0, NOISE_WORKING, 3)
        d = truth[k] + rng.normal(0.0, NOISE_DESTINATION, 3)
        stamp = time.time()
        msg.header.stamp.sec = int(stamp)
        msg.header.stamp.nanosec = int((stamp - int(stamp)) * 1e9)
        msg.fiducial_id = ids[k]
        msg.working_point.x, msg.working_point.y, msg.working_point.z = map(float, w)
        msg.destination_point.x, msg.destination_point.y, msg.destination_point.z = map(float, d)
        for _ in range(10_000):
            try:
                pub.publish(msg)
                break
            except RCLError:  # writer history full: the node is behind; wait and retry
                retries += 1
                time.sleep(0.001)
        else:
            raise RuntimeError("streamer: publish kept failing for 10 s")
        published += 1
    # Keep the writer alive until the node has every sample (reliable delivery needs it).
    from rclpy.duration import Duration
    acked = pub.wait_for_all_acked(Duration(seconds=30))
    return {"published": published, "rate": args.rate, "max_pairs": args.max_pairs,
            "seconds": t_end - t0,
            "publish_retries": retries, "all_acked": bool(acked), "lateness_max_s": lateness_max,
            "late_over_10ms": int(late_over_10ms), "holes": len(truth),
            "holes_with_id": sum(bool(i) for i in ids)}


def client(args, node, executor) -> dict:
    from geometry_msgs.msg import PointStamped
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from rbc_registration_interfaces.msg import RegistrationStatus
    from rbc_registration_interfaces.srv import CorrectTarget

    role = f"client{args.index}"
    ns = f"/{args.node_name}"
    valid = []
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    sub = node.create_subscription(RegistrationStatus, f"{ns}/status",
                                   lambda m: valid.append(m.model_valid), latched)
    cli = node.create_client(CorrectTarget, f"{ns}/correct_target")
    if not cli.wait_for_service(timeout_sec=DISCOVERY_TIMEOUT):
        raise RuntimeError(f"{role}: {ns}/correct_target did not appear")
    go = wait_go(args.workdir, role, lambda: executor.spin_once(timeout_sec=0.02))
    end = time.monotonic() + MODEL_TIMEOUT
    while not (valid and valid[-1]):  # the stream builds the first model within ~1 s
        if time.monotonic() > end:
            raise RuntimeError(f"{role}: no valid model after {MODEL_TIMEOUT} s")
        executor.spin_once(timeout_sec=0.02)
    node.destroy_subscription(sub)
    rng = np.random.default_rng(1000 + args.index)
    truth = rng.uniform([0.1, 0.1, 0.1], [0.8, 0.8, 0.5], (200, 3))  # inside the grid
    targets = to_working(truth)
    t0, t_end = go["t0"], go["t_end"]
    times, latencies, errors = [], [], []
    n_errors = 0
    request = CorrectTarget.Request(target=PointStamped())
    request.target.header.frame_id = WORKING_FRAME
    k = 0
    while True:
        start = time.monotonic()
        if start >= t_end:
            break
        j = k % len(targets)
        request.target.point.x, request.target.point.y, request.target.point.z = \
            map(float, targets[j])
        t = time.perf_counter()
        future = cli.call_async(request)
        executor.spin_until_future_complete(future, timeout_sec=args.timeout)
        latency = time.perf_counter() - t
        error = None
        if not future.done():
            cli.remove_pending_request(future)
            error = ("timeout", f"no answer within {args.timeout} s")
        elif future.exception() is not None:
            error = ("exception", repr(future.exception()))
        else:
            r = future.result()
            got = np.array([r.uncorrected.point.x, r.uncorrected.point.y, r.uncorrected.point.z])
            dest = np.array([r.destination.point.x, r.destination.point.y,
                             r.destination.point.z])
            if not r.success:
                error = ("success=false", r.message)
            elif not (np.all(np.isfinite(dest)) and np.linalg.norm(got - truth[j]) < 5e-3
                      and np.linalg.norm(dest - truth[j]) < 5e-3):
                error = ("wrong answer", f"target {j}: uncorrected {got}, destination {dest}, "
                                         f"truth {truth[j]}")
        times.append(round(start - t0, 6))
        latencies.append(round(latency, 7))
        if error:
            n_errors += 1
            if len(errors) < 1000:
                errors.append({"t": round(start - t0, 3), "kind": error[0],
                               "message": error[1][:300]})
        k += 1
        if args.think > 0:
            time.sleep(args.think)
    return {"index": args.index, "think_s": args.think, "timeout_s": args.timeout,
            "t": times, "latency_s": latencies, "n_errors": n_errors, "errors": errors}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("role", choices=["streamer", "client"])
    parser.add_argument("node_name")
    parser.add_argument("workdir")
    parser.add_argument("--rate", type=float, default=200.0, help="pairs per second")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-pairs", type=int, default=0, help="stop after this many (0: never)")
    parser.add_argument("--index", type=int, default=0, help="client number")
    parser.add_argument("--think", type=float, default=0.01, help="s between a client's calls")
    parser.add_argument("--timeout", type=float, default=5.0, help="s before a call times out")
    args = parser.parse_args()
    role = args.role if args.role == "streamer" else f"client{args.index}"

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    # SIGINT / SIGTERM (soak.py stopping us) end whatever runs at once, via KeyboardInterrupt.
    # (Set both: a shell starts background jobs with SIGINT ignored, and children inherit it.)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = rclpy.create_node(f"soak_{role}")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        work = streamer if args.role == "streamer" else client
        result = work(args, node, executor)
        write_json(args.workdir, role, result)
        return 0
    except KeyboardInterrupt:
        return 130
    except Exception as exc:  # noqa: BLE001 - reported to soak.py
        write_json(args.workdir, role, {"fatal": f"{type(exc).__name__}: {exc}"})
        print(f"{role}: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
