"""The demo a new user runs first (``scripts/demo.sh``): a synthetic RA-like cell (robot arm,
2D, 277 fiducial holes, 80 target holes) is written as a bag, replayed into a live
``registration_node``, the node corrects all targets, and the TRE with and without correction
is printed beside the rho decision; then ``evaluate`` writes the report directory offline and
the two are compared. The node is always stopped (also on Ctrl-C or an error).

Run with the loopback environment of ``scripts/env.sh`` (DDS stays on this machine).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import numpy as np

from .bag_commands import cell_messages
from .core.synthetic import make_cell
from .evaluate import evaluate_contents, settings_for, write_report_dir
from .io.bag import DEFAULT_TOPICS, read_bag, write_bag

NODE = "registration_node"


class DemoError(RuntimeError):
    """The demo could not complete; the message says which step and why."""


def _start_node(state_dir: str, log_path: Path) -> subprocess.Popen:
    args = [sys.executable, "-m", "rbc_registration.ros.node", "--ros-args",
            "-r", f"__node:={NODE}", "-p", "dimension:=2", "-p", f"state_dir:={state_dir}",
            "-p", "debounce_period:=0.1"]
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    env.pop("ROS_STATIC_PEERS", None)
    with open(log_path, "w") as log:
        return subprocess.Popen(args, env=env, stdout=log, stderr=subprocess.STDOUT)


def _stop_node(proc: Optional[subprocess.Popen]) -> None:
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


class _Client:
    """An rclpy context, a client node spinning in a thread, the node's latched status."""

    def __init__(self) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.signals import SignalHandlerOptions

        from rbc_registration_interfaces.msg import RegistrationStatus

        self.context = rclpy.Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node("rbc_demo_client", context=self.context)
        self.status: Any = None
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.node.create_subscription(RegistrationStatus, f"/{NODE}/status",
                                      self._on_status, latched)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def _on_status(self, msg: Any) -> None:
        self.status = msg

    def wait_status(self, predicate: Callable[[Any], bool], timeout: float, what: str,
                    node: subprocess.Popen) -> Any:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if node.poll() is not None:
                raise DemoError(f"registration_node exited with status {node.returncode} "
                                f"while waiting for {what}")
            status = self.status
            if status is not None and predicate(status):
                return status
            time.sleep(0.05)
        raise DemoError(f"timed out after {timeout:g} s waiting for {what}")

    def correct_targets(self, working: np.ndarray, timeout: float = 30.0) -> Any:
        from geometry_msgs.msg import PointStamped

        from rbc_registration_interfaces.srv import CorrectTargets

        client = self.node.create_client(CorrectTargets, f"/{NODE}/correct_targets")
        if not client.wait_for_service(timeout_sec=timeout):
            raise DemoError(f"service /{NODE}/correct_targets not available")
        request = CorrectTargets.Request()
        for p in working:
            t = PointStamped()
            t.header.frame_id = "tracker"
            t.point.x, t.point.y, t.point.z = float(p[0]), float(p[1]), 0.0
            request.targets.append(t)
        done = threading.Event()
        future = client.call_async(request)
        future.add_done_callback(lambda _: done.set())
        if not done.wait(timeout):
            raise DemoError("correct_targets did not answer")
        return future.result()

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self.thread.join(timeout=10)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def _fresh_bag_path(out: Path) -> Path:
    bag = out / "ra_cell_bag"
    if bag.exists():
        if not (bag / "metadata.yaml").exists():
            raise DemoError(f"{bag} exists and is not a bag; move it away")
        shutil.rmtree(bag)
    return bag


def run(out: Path, rate: float = 20.0, seed: int = 0, timeout: float = 60.0,
        log: Callable[[str], None] = print) -> dict[str, Any]:
    """The demo; returns what it printed as a dict (also written to ``out/demo.json``)."""
    t0 = time.monotonic()
    out.mkdir(parents=True, exist_ok=True)
    cell = make_cell("RA", seed=seed)
    n_meas = sum(len(m) for m in cell.fiducial_measurements)
    bag = _fresh_bag_path(out)
    log(f"[1/5] synthetic RA-like cell (seed {seed}): {len(cell.fiducial_ids)} fiducial holes "
        f"({n_meas} measurements, 20 ms apart), {len(cell.target_ids)} targets -> {bag}")
    write_bag(bag, cell_messages(cell), "mcap", progress=False)
    contents = read_bag(bag, progress=False)
    truth = np.array([m.destination[:2] for m in contents.targets])
    working = np.array([m.working[:2] for m in contents.targets])

    node = client = None
    state_dir = tempfile.mkdtemp(prefix="rbc_demo_state_")
    try:
        log(f"[2/5] starting registration_node (dimension:=2, state_dir:={state_dir}); "
            f"log {out / 'node.log'}")
        node = _start_node(state_dir, out / "node.log")
        client = _Client()
        client.wait_status(lambda s: True, timeout, "the node's first status", node)

        log(f"[3/5] replaying {bag.name} at {rate:g}x into /{NODE}/fiducial_pairs")
        from .replay import replay

        result = replay(bag, rate=rate, topics=[DEFAULT_TOPICS.fiducial_pairs], wait=10.0,
                        context=client.context, progress=False, log=log)
        log(f"      published {result.published} messages in {result.seconds:.1f} s; waiting "
            "for the model")
        status = client.wait_status(
            lambda s: (s.n_measurements + s.n_rejected >= n_meas and s.n_pending == 0
                       and s.model_valid and s.n_fiducials == len(cell.fiducial_ids)),
            timeout, f"all {len(cell.fiducial_ids)} fiducials in the model", node)

        log(f"[4/5] correct_targets for all {len(working)} targets")
        response = client.correct_targets(working)
        if not response.success:
            raise DemoError(f"correct_targets failed: {response.message}")
        corrected = np.array([[r.corrected.point.x, r.corrected.point.y]
                              for r in response.results])
        uncorrected = np.array([[r.uncorrected.point.x, r.uncorrected.point.y]
                                for r in response.results])
        tre_u = np.linalg.norm(uncorrected - truth, axis=1) * 1e3
        tre_c = np.linalg.norm(corrected - truth, axis=1) * 1e3
        applied = bool(response.results[0].correction_applied)
        log(f"      rho = sigma_L0 / sigma = {status.rho:.3g} (sigma_L0 "
            f"{status.sigma_l[0] * 1e3:.3g} mm, sigma {status.sigma * 1e3:.3g} mm from "
            f"{status.sigma_source}) -> decision: {status.recommendation}; corrections "
            f"{'applied' if applied else 'not applied'}")
        log(f"      TRE [mm]       median    mean     max")
        log(f"      uncorrected  {np.median(tre_u):7.3f} {tre_u.mean():7.3f} {tre_u.max():7.3f}")
        log(f"      corrected    {np.median(tre_c):7.3f} {tre_c.mean():7.3f} {tre_c.max():7.3f}")
        log(f"      corrections improved {np.mean(tre_c < tre_u) * 100:.0f}% of targets")

        log(f"[5/5] offline: evaluate {bag.name} -> {out}/")
        ev = evaluate_contents(contents, settings_for(2, {}))
        write_report_dir(ev, out, "Demo: RA-like cell")
        offline = np.array([t["corrected"] for t in ev.report["targets"]])
        diff = float(np.abs(offline - corrected).max())
        rho_diff = abs(ev.model.rho - status.rho)
        agree = diff < 1e-9 and rho_diff < 1e-9
        log(f"      live node vs offline evaluate: max |corrected| difference {diff:.2g} m, "
            f"rho difference {rho_diff:.2g} -> {'agree' if agree else 'DIFFER'}")
    finally:
        if client is not None:
            client.close()
        _stop_node(node)
        shutil.rmtree(state_dir, ignore_errors=True)
    summary = {"rho": status.rho, "recommendation": status.recommendation,
               "corrections_applied": applied, "n_fiducials": status.n_fiducials,
               "n_measurements": status.n_measurements, "unit": "mm",
               "tre_u_median": float(np.median(tre_u)), "tre_c_median": float(np.median(tre_c)),
               "fraction_improved": float(np.mean(tre_c < tre_u)),
               "targets": [{"id": tid, "tre_u": float(u), "tre_c": float(c)}
                           for tid, u, c in zip(cell.target_ids, tre_u, tre_c)],
               "offline_max_difference_m": diff, "agree": agree,
               "seconds": time.monotonic() - t0}
    (out / "demo.json").write_text(json.dumps(summary, indent=2) + "\n")
    log(f"done in {summary['seconds']:.1f} s: {out}/report.md, figures, report.json, demo.json, "
        "node.log; the node is stopped")
    return summary


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m rbc_registration.demo [--out DIR] [--rate R]``; exit 1 when live and offline
    results differ or a step failed, 130 on Ctrl-C."""
    p = argparse.ArgumentParser(prog="rbc_registration.demo", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=Path("demo_out"), help="report directory")
    p.add_argument("--rate", type=float, default=20.0, help="replay speed-up (default 20)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--timeout", type=float, default=60.0, help="seconds per waiting step")
    args = p.parse_args(argv)
    try:
        summary = run(args.out, args.rate, args.seed, args.timeout)
    except KeyboardInterrupt:
        print("demo: interrupted; the node is stopped", file=sys.stderr)
        return 130
    except (DemoError, ValueError, OSError, ImportError) as exc:
        print(f"demo: error: {exc}", file=sys.stderr)
        return 1
    return 0 if summary["agree"] else 1


if __name__ == "__main__":
    sys.exit(main())
