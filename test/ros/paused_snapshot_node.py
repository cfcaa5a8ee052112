"""``registration_node`` whose snapshot writes stop half way (test/pipeline/paused_writer.py),
for the SIGKILL-inside-a-snapshot fault test. Usage (ROS arguments as for the node):
``python paused_snapshot_node.py MARKER --ros-args ...``."""

import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "pipeline"))

from paused_writer import paused_write_atomic  # noqa: E402

from rbc_registration.ros.node import main  # noqa: E402

if __name__ == "__main__":
    marker = sys.argv.pop(1)
    main(sys.argv, write_snapshot=paused_write_atomic(marker))
