"""registration_node that receives a real SIGTERM at a chosen moment (test helper).

``RBC_SIGTERM_AT=make`` (default): before the node is created, the process sends itself SIGTERM
and waits until rclpy's signal handler has shut the context down: whatever the node then
creates fails on the invalid context, as it does when ``ros2 launch`` stops a node that is
still starting.

``RBC_SIGTERM_AT=spin``: the executor spins a few times, then the signal lands between
``Executor.spin``'s context check and its next ``spin_once`` (which then fails to make its wait
set on the shut-down context): the race a SIGTERM during spinning hits now and then.

Arguments: the node's ``--ros-args``.
"""

import os
import signal
import sys
import time

import rclpy

from rbc_registration.ros import node as node_module


def sigterm_and_wait() -> None:
    os.kill(os.getpid(), signal.SIGTERM)
    deadline = time.monotonic() + 10
    while rclpy.ok() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not rclpy.ok(), "rclpy's SIGTERM handler did not shut the context down"


if os.environ.get("RBC_SIGTERM_AT", "make") == "spin":
    class SignalledExecutor(node_module.LaneExecutor):
        def spin(self) -> None:
            for _ in range(5):
                self.spin_once(timeout_sec=0.05)
            # spin's loop has checked the context: the signal comes now.
            sigterm_and_wait()
            self.spin_once()

    node_module.LaneExecutor = SignalledExecutor
else:
    real = node_module.RegistrationNode

    def stopped_while_starting(**options):
        sigterm_and_wait()
        return real(**options)

    node_module.RegistrationNode = stopped_while_starting
node_module.main(sys.argv[1:])
