"""Fixtures of the ROS tests (see ros_helpers.py for the helpers themselves)."""

import pytest


@pytest.fixture
def ros_harness():
    """A :class:`ros_helpers.RosHarness` (own Context, spinning executor, client node) for one
    test; stopped (spin thread joined, context shut down) afterwards."""
    pytest.importorskip("rclpy")
    from ros_helpers import RosHarness

    harness = RosHarness()
    try:
        yield harness
    finally:
        harness.stop()
