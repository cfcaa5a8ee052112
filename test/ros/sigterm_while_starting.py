"""registration_node that receives a real SIGTERM while its node is being made (test helper).

The node class is wrapped so that, before the node is created, the process sends itself SIGTERM
and waits until rclpy's signal handler has shut the context down: whatever the node then
creates fails on the invalid context, as it does when ``ros2 launch`` stops a node that is
still starting. Arguments: the node's ``--ros-args``.
"""

import os
import signal
import sys
import time

import rclpy

from rbc_registration.ros import node as node_module

real = node_module.RegistrationNode


def stopped_while_starting(**options):
    os.kill(os.getpid(), signal.SIGTERM)
    deadline = time.monotonic() + 10
    while rclpy.ok() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not rclpy.ok(), "rclpy's SIGTERM handler did not shut the context down"
    return real(**options)


node_module.RegistrationNode = stopped_while_starting
node_module.main(sys.argv[1:])
