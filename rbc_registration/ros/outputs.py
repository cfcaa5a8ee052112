"""The event callbacks of the node's publishers (``~/status``, ``~/transform``,
``~/transform_uncorrected``, ``~/markers``, ``/diagnostics``, ``/tf_static``): none.

rclpy's defaults give every publisher two event handlers (offered incompatible QoS, incompatible
type), each a waitable that every executor wake adds to its wait set and checks in Python:
about 3 µs per handler per wake here, 12 handlers for the node's six publishers, ~37 µs of each
``~/correct_target`` round trip (`benchmarks/RESULTS.md`). A subscriber with incompatible QoS or
type reports it on its side (rclpy's and rclcpp's defaults, ``ros2 topic echo``). The node's
input subscriptions keep their handlers: the node warns about an incompatible publisher of
measurements.
"""

from __future__ import annotations

from rclpy.event_handler import PublisherEventCallbacks


def output_events() -> PublisherEventCallbacks:
    """Publisher event callbacks without rclpy's default handlers (module docstring)."""
    return PublisherEventCallbacks(use_default_callbacks=False)
