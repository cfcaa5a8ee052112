"""Load and soak test of registration_node, all processes on this machine, DDS on loopback.

Starts the node (``python -m rbc_registration.ros.node``, a temporary ``state_dir``, otherwise
its defaults), one streamer process publishing ``FiducialPair`` at a steady ``--rate`` (200/s:
48 holes visited in shuffled rounds with noise, half of them with ids, half without) and
``--clients`` (4) client processes, each calling ``~/correct_target`` in a loop with
``--think`` (10 ms) between calls (``--think 0``: back-to-back), for ``--duration`` seconds.
Every call's latency and every error (failed call, ``success=false``, timeout after
``--call-timeout``, or an answer more than 5 mm from the truth) is recorded; every ``--sample``
seconds the node's RSS (/proc/PID/status VmRSS), CPU, threads, open files and its
``~/status`` counters. At the end: every published pair must have been accepted (the node's
``n_measurements``) and journaled (lines of ``journal.jsonl``), nothing rejected, no error.
Clients start calling once the first model exists (~2 s into the stream: the longest debounce);
their latencies count from then. The run is timed by the shared CLOCK_MONOTONIC: every child
works from ``t0`` to ``t0 + duration`` and stops by itself.

    source scripts/env.sh && python benchmarks/soak.py --duration 600     # ~11 min
    python benchmarks/soak.py --duration 20 --out /tmp/soak                # quick check
    python benchmarks/soak.py --max-pairs 480 --duration 300    # services only, fixed model
    python benchmarks/soak.py --node-env OPENBLAS_NUM_THREADS=1  # an environment for the node

Writes ``soak.json`` (raw results), ``soak.md`` (summary, also printed), ``soak.png`` (RSS,
CPU and latency over time) and ``logs/`` into ``--out``. Exit 0 when every check passed, 1
when one failed, 2 when the run could not be carried out. All child processes are stopped at
the end, on Ctrl-C and on errors (and get SIGTERM if this process dies).

DDS stays on loopback: ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST is set here and inherited by
every child; ROS_DOMAIN_ID is derived from this process's id (1..101) unless ``--domain``.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)

import soak_report  # noqa: E402

CLK_TCK = os.sysconf("SC_CLK_TCK")
STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}
READY_TIMEOUT = 120.0


def set_environment(domain: int, log_dir: str) -> None:
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_STATIC_PEERS", None)
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    os.environ["ROS_LOG_DIR"] = log_dir  # rclpy's log files, not ~/.ros/log
    if not os.environ.get("AMENT_PREFIX_PATH") and os.path.isdir(
            os.path.join(sys.prefix, "share", "ament_index")):
        os.environ["AMENT_PREFIX_PATH"] = sys.prefix


def _die_with_parent() -> None:  # runs in the child before exec
    ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def spawn(cmd: list[str], log_path: str, extra_env: dict | None = None) -> subprocess.Popen:
    with open(log_path, "w") as log:
        return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT,
                                env=dict(os.environ, **(extra_env or {})),
                                preexec_fn=_die_with_parent, cwd=ROOT)


def stop(procs: list[subprocess.Popen], timeout: float = 15.0) -> None:
    """SIGINT to every process still running, then SIGKILL to those not gone after ``timeout``."""
    for proc in procs:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    end = time.monotonic() + timeout
    for proc in procs:
        try:
            proc.wait(timeout=max(0.1, end - time.monotonic()))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def proc_sample(pid: int) -> dict:
    """RSS, peak RSS [MB], threads, open files and CPU ticks of ``pid`` from /proc."""
    out = {}
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            key, _, value = line.partition(":")
            if key in ("VmRSS", "VmHWM"):
                out[key] = int(value.split()[0]) / 1024.0
            elif key == "Threads":
                out["threads"] = int(value)
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    out["ticks"] = int(fields[11]) + int(fields[12])  # utime + stime
    out["fds"] = len(os.listdir(f"/proc/{pid}/fd"))
    return out


def machine_ticks() -> tuple[int, int]:
    """(busy, total) jiffies of all cores from /proc/stat."""
    with open("/proc/stat") as f:
        values = [int(v) for v in f.readline().split()[1:]]
    idle = values[3] + values[4]
    return sum(values) - idle, sum(values)


class StatusWatch:
    """The node's latest ``~/status``, received by an rclpy node spinning in a thread."""

    def __init__(self, node_name: str) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions

        from rbc_registration_interfaces.msg import RegistrationStatus

        self._rclpy = rclpy
        self.latest = None
        self.received = 0.0
        # Keep this script's SIGINT / SIGTERM handling (stop every child, then exit), and let
        # only the main thread receive them: the threads of rclpy / DDS, started from here,
        # inherit the blocked mask, so a signal interrupts the main thread's sleep at once.
        signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
        try:
            rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
            self.node = rclpy.create_node("soak_monitor")
            qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.node.create_subscription(RegistrationStatus, f"/{node_name}/status",
                                          self._on_status, qos)
            self.executor = SingleThreadedExecutor()
            self.executor.add_node(self.node)
            self._thread = threading.Thread(target=self.executor.spin, daemon=True)
            self._thread.start()
        finally:
            signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)

    def _on_status(self, msg) -> None:
        self.latest, self.received = msg, time.monotonic()

    def stop(self) -> None:
        """Stop and join the spin thread, then shut rclpy down."""
        self.executor.shutdown()
        self._thread.join(timeout=10.0)
        self.node.destroy_node()
        self._rclpy.try_shutdown()


def journal_counts(path: str) -> dict:
    counts = {"lines": 0, "measurements": 0, "header": 0, "other": 0, "bytes": 0}
    if not os.path.exists(path):
        return counts
    counts["bytes"] = os.path.getsize(path)
    with open(path, "rb") as f:
        for line in f:
            counts["lines"] += 1
            if line.startswith(b'{"t":"m"'):
                counts["measurements"] += 1
            elif line.startswith(b'{"t":"h"'):
                counts["header"] += 1
            else:
                counts["other"] += 1
    return counts


def wait_until(predicate, timeout: float, what: str, procs=()) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        for name, proc in procs:
            if proc.poll() is not None:
                raise RuntimeError(f"{name} exited with {proc.returncode} while waiting for "
                                   f"{what}")
        if time.monotonic() > end:
            raise RuntimeError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.1)


def run(args, workdir: str, out: str) -> dict:
    state_dir = os.path.join(workdir, "state")
    logs = os.path.join(out, "logs")
    os.makedirs(logs, exist_ok=True)
    name = f"soak_registration_{os.getpid()}"
    procs: list[tuple[str, subprocess.Popen]] = []
    watch = None
    try:
        node = spawn([sys.executable, "-m", "rbc_registration.ros.node", "--ros-args",
                      "-r", f"__node:={name}", "-p", f"state_dir:={state_dir}"],
                     os.path.join(logs, "node.log"), node_env(args))
        procs.append(("node", node))
        script = os.path.join(HERE, "soak_procs.py")
        procs.append(("streamer", spawn([sys.executable, script, "streamer", name, workdir,
                                         "--rate", str(args.rate),
                                         "--max-pairs", str(args.max_pairs)],
                                        os.path.join(logs, "streamer.log"))))
        for k in range(args.clients):
            procs.append((f"client{k}", spawn(
                [sys.executable, script, "client", name, workdir, "--index", str(k),
                 "--think", str(args.think), "--timeout", str(args.call_timeout)],
                os.path.join(logs, f"client{k}.log"))))
        watch = StatusWatch(name)  # after the children: no thread while forking
        wait_until(lambda: watch.latest is not None, READY_TIMEOUT, "the node's status", procs)
        roles = [n for n, _ in procs[1:]]
        wait_until(lambda: all(os.path.exists(os.path.join(workdir, f"{r}.ready"))
                               for r in roles), READY_TIMEOUT, "the children", procs)
        samples = []
        mine = [p.pid for _, p in procs[1:]] + [os.getpid()]

        def sample(t: float, last: dict) -> dict:
            try:
                s = proc_sample(node.pid)
            except OSError:
                raise RuntimeError(f"the node exited ({node.poll()}); see "
                                   f"{logs}/node.log") from None
            busy, total = machine_ticks()
            soak_ticks = s["ticks"] + sum(_ticks(pid) for pid in mine)
            st = watch.latest
            row = {"t": round(t, 3), "rss_mb": round(s["VmRSS"], 3),
                   "hwm_mb": round(s["VmHWM"], 3), "threads": s["threads"], "fds": s["fds"],
                   "load1": os.getloadavg()[0], "n_measurements": st.n_measurements,
                   "n_pending": st.n_pending, "n_rejected": st.n_rejected,
                   "n_fiducials": st.n_fiducials, "model_valid": st.model_valid,
                   "status_age_s": round(time.monotonic() - watch.received, 3),
                   "_ticks": s["ticks"], "_soak": soak_ticks, "_busy": busy, "_total": total,
                   "_time": time.monotonic()}
            if last:
                dt = row["_time"] - last["_time"]
                row["node_cpu_pct"] = round(100 * (row["_ticks"] - last["_ticks"]) / CLK_TCK
                                            / dt, 1)
                row["soak_cpu_cores"] = round((row["_soak"] - last["_soak"]) / CLK_TCK / dt, 3)
                row["machine_cpu_cores"] = round(
                    (os.cpu_count() or 1) * (busy - last["_busy"]) / max(1, total - last["_total"]),
                    3)
            return row

        before = sample(-1.0, {})  # the node up, nothing streamed yet
        t0 = time.monotonic() + 1.0
        t_end = t0 + args.duration
        with open(os.path.join(workdir, "go.json.tmp"), "w") as f:
            json.dump({"t0": t0, "t_end": t_end}, f)
        os.replace(os.path.join(workdir, "go.json.tmp"), os.path.join(workdir, "go.json"))
        print(f"soak: go for {args.duration:g} s ({args.clients} clients, {args.rate:g} pairs/s, "
              f"domain {os.environ['ROS_DOMAIN_ID']}, out {out})", flush=True)
        last = before
        next_t = t0
        while next_t <= t_end + 1e-9:
            time.sleep(max(0.0, next_t - time.monotonic()))
            last = sample(time.monotonic() - t0, last)
            samples.append(last)
            for pname, proc in procs:
                if proc.poll() is not None and proc.returncode != 0:
                    raise RuntimeError(f"{pname} exited with {proc.returncode} during the run "
                                       f"(see {logs}/{pname}.log)")
            if args.progress and len(samples) % max(1, int(60 / args.sample)) == 0:
                print(f"  t={last['t']:.0f} s rss {last['rss_mb']:.1f} MB, "
                      f"{last['n_measurements']} accepted, load {last['load1']:.2f}", flush=True)
            next_t += args.sample
        # The children stop by themselves at t_end and write their results.
        for pname, proc in procs[1:]:
            try:
                proc.wait(timeout=90)
            except subprocess.TimeoutExpired:
                raise RuntimeError(f"{pname} did not stop after the run") from None
        children = {}
        for pname, proc in procs[1:]:
            path = os.path.join(workdir, f"{pname}.json")
            children[pname] = json.load(open(path)) if os.path.exists(path) else {
                "fatal": "no result file"}
            children[pname]["exit_code"] = proc.returncode
        published = children["streamer"].get("published", -1)
        try:
            wait_until(lambda: watch.latest.n_measurements + watch.latest.n_rejected
                       >= published, 60, "the node to report every pair")
        except RuntimeError as exc:
            print(f"soak: {exc}", file=sys.stderr)
        time.sleep(1.5)  # more than one status period (1 s): the last status is current
        final = sample(time.monotonic() - t0, last)
        status = watch.latest
        stop([node])
        return {"settings": {"duration_s": args.duration, "clients": args.clients,
                             "rate": args.rate, "max_pairs": args.max_pairs,
                             "think_s": args.think,
                             "call_timeout_s": args.call_timeout, "sample_s": args.sample,
                             "node_parameters": "defaults + state_dir (temporary)",
                             "node_env": node_env(args),
                             "domain": int(os.environ["ROS_DOMAIN_ID"]), "node_name": name},
                "machine": soak_report.machine(),
                "before": _public(before), "samples": [_public(s) for s in samples],
                "final": _public(final), "children": children,
                "node_final_status": {"n_measurements": status.n_measurements,
                                      "n_rejected": status.n_rejected,
                                      "n_fiducials": status.n_fiducials,
                                      "sigma": status.sigma, "rho": status.rho,
                                      "recommendation": status.recommendation,
                                      "model_valid": status.model_valid,
                                      "message": status.message},
                "node_exit_code": node.returncode,
                "journal": journal_counts(os.path.join(state_dir, "journal.jsonl")),
                "node_log_bytes": os.path.getsize(os.path.join(logs, "node.log"))}
    finally:
        stop([proc for _, proc in reversed(procs)])
        if watch is not None:
            watch.stop()


def node_env(args) -> dict:
    """``--node-env KEY=VALUE`` options as a dictionary (for the node process only)."""
    env = {}
    for item in args.node_env:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"--node-env must be KEY=VALUE, got {item!r}")
        env[key] = value
    return env


def _ticks(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return int(fields[11]) + int(fields[12])
    except (OSError, IndexError):
        return 0


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def _public(row: dict) -> dict:
    return {k: v for k, v in row.items() if not k.startswith("_")}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=600.0, help="seconds of load")
    parser.add_argument("--clients", type=int, default=4, help="correct_target client processes")
    parser.add_argument("--rate", type=float, default=200.0, help="FiducialPairs per second")
    parser.add_argument("--max-pairs", type=int, default=0,
                        help="the streamer stops after this many pairs (0: streams the whole "
                             "run); e.g. 480 for a services-only run on a fixed model")
    parser.add_argument("--think", type=float, default=0.01,
                        help="seconds a client waits between calls (0: back-to-back)")
    parser.add_argument("--call-timeout", type=float, default=5.0,
                        help="seconds before a call counts as timed out")
    parser.add_argument("--sample", type=float, default=5.0, help="seconds between samples")
    parser.add_argument("--out", default="soak_out", help="directory for the results")
    parser.add_argument("--domain", type=int, default=os.getpid() % 101 + 1,
                        help="ROS_DOMAIN_ID (default: from this process's id)")
    parser.add_argument("--node-env", action="append", default=[], metavar="KEY=VALUE",
                        help="an environment variable for the node process only (repeatable), "
                             "e.g. OPENBLAS_NUM_THREADS=1")
    parser.add_argument("--progress", action="store_true", help="print a line every minute")
    args = parser.parse_args()
    if not (args.duration > 0 and args.clients >= 1 and args.rate > 0 and args.sample > 0
            and 1 <= args.domain <= 101):
        parser.error("need duration > 0, clients >= 1, rate > 0, sample > 0, 1 <= domain <= 101")
    try:
        node_env(args)
    except ValueError as exc:
        parser.error(str(exc))
    out = os.path.abspath(args.out)
    os.makedirs(out, exist_ok=True)
    workdir = tempfile.mkdtemp(prefix="rbc_soak_")
    set_environment(args.domain, os.path.join(workdir, "ros_log"))
    # Ctrl-C, or SIGTERM (e.g. a CI timeout): stop every child and exit. SIGINT is set too, as a
    # shell starts background jobs with it ignored.
    signal.signal(signal.SIGINT, _interrupt)
    signal.signal(signal.SIGTERM, _interrupt)
    try:
        results = run(args, workdir, out)
    except KeyboardInterrupt:
        print("soak: interrupted; every child process stopped", file=sys.stderr)
        return 2
    except RuntimeError as exc:
        print(f"soak: FAILED to run: {exc}", file=sys.stderr)
        return 2
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    summary = results["summary"] = soak_report.summarise(results)
    with open(os.path.join(out, "soak.json"), "w") as f:
        json.dump(results, f)
    markdown = soak_report.markdown(results, summary)
    with open(os.path.join(out, "soak.md"), "w") as f:
        f.write(markdown)
    soak_report.plot(results, os.path.join(out, "soak.png"))
    print(markdown)
    failed = [name for name, ok in summary["checks"].items() if not ok]
    if failed:
        print(f"soak: FAILED checks: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
