"""Test-wide set-up: keep DDS on loopback and give each test process its own ROS domain.

This runs before any test module is imported, so before anything imports rclpy. Subprocesses
started by tests inherit the variables through ``os.environ``. Nothing here imports rclpy: pure
tests must be able to prove that ``rbc_registration.core`` never loads it.
"""

import os
import sys

import pytest

# One BLAS thread everywhere, as the console scripts run (rbc_registration/runtime.py sets it
# there), set before numpy is imported: tests that compare a subprocess's numbers with in-process
# ones (kriging's optimiser follows the summation order) then see the same BLAS in both.
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

# Discovery only on this machine, and no static peers that could point elsewhere.
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.pop('ROS_STATIC_PEERS', None)
os.environ.pop('ROS_LOCALHOST_ONLY', None)  # deprecated in favour of the range above
os.environ.setdefault('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
# One domain per test process (1..101: higher ids give Fast DDS ports beyond the usual
# ephemeral-port floor), so concurrent runs of the suite, or xdist workers, never talk to each
# other.
ROS_DOMAIN_ID = os.getpid() % 101 + 1
os.environ['ROS_DOMAIN_ID'] = str(ROS_DOMAIN_ID)
# In the pip venv (scripts/bootstrap.sh) the ament index is the venv prefix; scripts/env.sh sets
# this too, but plain `.venv/bin/python -m pytest` (an IDE) does not. A sourced ROS keeps its own.
if not os.environ.get('AMENT_PREFIX_PATH') and os.path.isdir(
        os.path.join(sys.prefix, 'share', 'ament_index')):
    os.environ['AMENT_PREFIX_PATH'] = sys.prefix


def pytest_configure(config):
    config.addinivalue_line(
        'markers', 'ros: needs rclpy and the ROS middleware (runs on loopback only)')
    # lark-parser 0.12, pulled in by the ROS wheels' rosidl_parser, imports deprecated modules.
    config.addinivalue_line(
        'filterwarnings', r'ignore:module .sre_.* is deprecated:DeprecationWarning:lark\.utils')


@pytest.fixture
def ros_context():
    """
    Yield an initialised ``rclpy.Context`` of this test alone and shut it down afterwards.

    Stop and join every thread that spins an executor on it before the test returns:
    shutting a context down under a spinning thread can abort the process.
    """
    import rclpy

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=ROS_DOMAIN_ID)
    try:
        yield context
    finally:
        if context.ok():
            rclpy.shutdown(context=context)
