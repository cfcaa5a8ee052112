"""Input subscriptions taking the queued messages in one executor wake-up (ros/batching.py):
the helper on fake subscriptions, and the node in process with an executor spun by hand."""

import itertools
import os

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("rbc_registration_interfaces.msg")

from rclpy._rclpy_pybind11 import InvalidHandle  # noqa: E402
from rclpy.duration import Duration  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from rbc_registration.pipeline.journal_records import JOURNAL_NAME  # noqa: E402
from rbc_registration.pipeline.settings import SPECS  # noqa: E402
from rbc_registration.ros.batching import batched_subscription, take_queued  # noqa: E402
from rbc_registration.ros.node import INPUT, RegistrationNode  # noqa: E402
from rbc_registration_interfaces.msg import FiducialPair  # noqa: E402

from ros_helpers import domain_id, expected_state, make_cell, pair_msg, wait_for  # noqa: E402

pytestmark = pytest.mark.ros


class FakeHandle:
    """``Subscription.handle``: a queue of messages; counts the ``with`` blocks around takes."""

    def __init__(self, queue, destroyed_after=None):
        self.queue, self.entered, self.takes = list(queue), 0, []
        self.destroyed_after = destroyed_after

    def __enter__(self):
        if self.destroyed_after is not None and self.entered >= self.destroyed_after:
            raise InvalidHandle("destroyed")
        self.entered += 1
        return self

    def __exit__(self, *exc):
        return False

    def take_message(self, msg_type, raw):
        self.takes.append((msg_type, raw))
        return (self.queue.pop(0), "info") if self.queue else None


class FakeSubscription:
    msg_type, raw = "FiducialPair", False

    def __init__(self, queue, destroyed_after=None):
        self.handle = FakeHandle(queue, destroyed_after)


def test_take_queued_takes_in_order_up_to_the_limit():
    sub, got = FakeSubscription(["a", "b", "c", "d"]), []
    assert take_queued(sub, got.append, 3) == 3
    assert got == ["a", "b", "c"] and sub.handle.queue == ["d"]
    assert sub.handle.takes == [("FiducialPair", False)] * 3   # the executor's take arguments
    assert sub.handle.entered == 3                              # each take inside the handle


def test_take_queued_stops_at_the_first_empty_take_and_never_waits():
    sub, got = FakeSubscription(["a"]), []
    assert take_queued(sub, got.append, 10) == 1
    assert got == ["a"] and len(sub.handle.takes) == 2
    assert take_queued(sub, got.append, 10) == 0


@pytest.mark.parametrize("limit", [0, -1])
def test_take_queued_takes_nothing_without_a_positive_limit(limit):
    sub, got = FakeSubscription(["a"]), []
    assert take_queued(sub, got.append, limit) == 0
    assert got == [] and sub.handle.takes == []


def test_take_queued_ends_when_the_subscription_is_destroyed():
    sub, got = FakeSubscription(["a", "b", "c"], destroyed_after=1), []
    assert take_queued(sub, got.append, 5) == 1
    assert got == ["a"]


class FakeNode:
    """``create_subscription`` returning a fake subscription with ``queue`` waiting on it."""

    def __init__(self, queue):
        self.queue, self.lines = queue, []

    def get_logger(self):
        return self

    def error(self, line):
        self.lines.append(line)

    def create_subscription(self, msg_type, topic, callback, qos, callback_group=None):
        self.sub = FakeSubscription(self.queue)
        self.sub.callback = callback
        return self.sub


def test_a_batch_guards_each_message_and_reads_the_batch_size_each_time():
    got, size = [], [3]

    def callback(msg):
        if msg == "bad":
            raise RuntimeError("broken message")
        got.append(msg)

    node = FakeNode(["bad", "b", "c", "d", "e", "f"])
    sub = batched_subscription(node, "FiducialPair", "~/fiducial_pairs", callback, None, None,
                               lambda: size[0])
    sub.callback("a")                       # the executor hands over "a": 2 more are taken
    assert got == ["a", "b"]                # "bad" dropped with a log line, the batch went on
    assert node.lines == ["~/fiducial_pairs: message dropped: RuntimeError: broken message"]
    size[0] = 1                             # input_batch changed: one message per wake-up
    sub.callback("x")
    assert got == ["a", "b", "x"] and sub.handle.queue == ["c", "d", "e", "f"]


_names = itertools.count()


class TestNodeBatches:
    """The node on a SingleThreadedExecutor spun by hand, so each ``spin_once`` is one wake-up
    handling one ready entity; the pairs are all in the node's reader (acknowledged) first."""

    def setup_method(self):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id())
        self.executor = SingleThreadedExecutor(context=self.context)
        self.nodes = []

    def teardown_method(self):
        self.executor.shutdown()
        for node in self.nodes:
            node.destroy_node()
        rclpy.shutdown(context=self.context)

    def make_node(self, **params):
        name = f"batch_{os.getpid()}_{next(_names)}"
        params = {"debounce_period": 60.0, "status_period": 3600.0, "state_dir": "", **params}
        node = RegistrationNode(name, context=self.context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()])
        self.nodes.append(node)
        self.executor.add_node(node)
        client = rclpy.create_node(f"{name}_client", context=self.context)
        self.nodes.append(client)
        pub = client.create_publisher(FiducialPair, f"/{name}/fiducial_pairs", INPUT["reliable"])
        wait_for(lambda: pub.get_subscription_count() > 0, what="the node's subscription")
        return node, pub

    def queue(self, pub, cell, indices):
        for k in indices:
            pub.publish(pair_msg(cell, k, stamp_s=100.0 + k))
        assert pub.wait_for_all_acked(Duration(seconds=10.0)), "pairs not acknowledged"

    def wake_until_counted(self, node, at_least):
        for _ in range(1000):
            if node.status().n_measurements >= at_least:
                return node.status().n_measurements
            self.executor.spin_once(timeout_sec=0.05)
        raise AssertionError(f"fewer than {at_least} measurements counted")

    def test_one_wake_up_takes_input_batch_queued_pairs(self, tmp_path):
        cell = make_cell()
        node, pub = self.make_node(input_batch=10, state_dir=str(tmp_path))
        self.queue(pub, cell, range(25))
        assert self.wake_until_counted(node, 1) == 10    # the first wake-up: 1 + 9 queued
        assert self.wake_until_counted(node, 11) == 20
        assert self.wake_until_counted(node, 21) == 25   # the last: only the 5 left
        node.set_parameters([Parameter("input_batch", value=1)])
        self.queue(pub, cell, range(25, 28))
        assert self.wake_until_counted(node, 26) == 26   # one pair per wake-up
        # Every counted pair is journaled, and the store is the one of the pairs in order.
        with open(tmp_path / JOURNAL_NAME) as f:
            assert sum(1 for line in f if '"t":"m"' in line) == 26
        self.wake_until_counted(node, 28)
        want = expected_state(cell, range(28)).fiducials
        got = node._ingest.fiducial_set()
        assert list(got.ids) == list(want.ids)
        np.testing.assert_array_equal(got.working, want.working)
        np.testing.assert_array_equal(got.destination, want.destination)

    def test_input_batch_is_validated(self):
        node, _ = self.make_node()
        assert node._settings.input_batch == SPECS["input_batch"].default
        result = node.set_parameters([Parameter("input_batch", value=0)])[0]
        assert not result.successful and "input_batch" in result.reason
        assert node._settings.input_batch == SPECS["input_batch"].default
