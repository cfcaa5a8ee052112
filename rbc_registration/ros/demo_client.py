"""The demo's ROS client (:mod:`.demo`): an rclpy context and a client node spinning in a thread,
the node's latched status, and ``~/correct_targets`` calls."""

from __future__ import annotations

import subprocess
import threading
import time
from typing import Any, Callable

import numpy as np

from ..core.errors import OperationError

NODE = "registration_node"


class DemoError(OperationError):
    """The demo could not complete; the message says which step and why."""


class DemoClient:
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
