"""Oversized ``~/correct_targets`` requests cost the node nothing, and one client's large request
never holds up another client's ``~/correct_target`` (a real node process).

- More than CorrectTargets holds (100,000 targets, the maximum of ``max_targets``): the
  client's middleware refuses to send it; the node never sees it and answers as before.
- A large request within the bound (taken in the ``~/correct_targets`` lane, ros/lanes.py):
  another client's ``~/correct_target`` calls, one after the other, keep being answered while
  it is taken and answered.
"""

import os
import threading
import time

import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("rbc_registration_interfaces.msg")

from geometry_msgs.msg import PointStamped  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402

from rbc_registration.pipeline.settings import SPECS  # noqa: E402
from rbc_registration_interfaces.msg import FiducialPair, RegistrationStatus  # noqa: E402
from rbc_registration_interfaces.srv import CorrectTarget, CorrectTargets  # noqa: E402

from ros_helpers import (RosTestBase, make_cell, pair_msg, start_test_node,  # noqa: E402
                         stop_process, target_msg, wait_for)

pytestmark = pytest.mark.ros
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
SRV = os.path.join(os.path.dirname(__file__), "..", "..", "msg_docs",
                   "rbc_registration_interfaces", "srv", "CorrectTargets.srv")
#: What CorrectTargets holds: the maximum of max_targets.
BOUND = int(SPECS["max_targets"].high)


def test_the_interface_bound_is_max_targets_maximum():
    with open(SRV) as f:
        fields = [line.split("#")[0].split() for line in f if line.split("#")[0].strip()]
    assert ["geometry_msgs/PointStamped[<=%d]" % BOUND, "targets"] in fields


class TestOversized(RosTestBase):
    @classmethod
    def setup_class(cls):
        super().setup_class()
        cls.name = f"reg_oversized_{os.getpid()}"
        cls.log = open(f"/tmp/{cls.name}.log", "w")
        cls.proc = start_test_node(cls.name, log=cls.log)
        statuses = []
        cls.ros.client.create_subscription(RegistrationStatus, f"/{cls.name}/status",
                                           statuses.append, LATCHED)
        pub = cls.ros.client.create_publisher(FiducialPair, f"/{cls.name}/fiducial_pairs", 100)
        cls.cell = make_cell(seed=5)
        wait_for(lambda: pub.get_subscription_count() > 0, 30, "the node's subscription")
        for k in range(len(cls.cell["fid"])):
            pub.publish(pair_msg(cls.cell, k))
        wait_for(lambda: statuses and statuses[-1].model_valid, 60, "a model")

    @classmethod
    def teardown_class(cls):
        stop_process(cls.proc)
        cls.log.close()
        super().teardown_class()

    def correct_one(self):
        return self.ros.call(CorrectTarget, f"/{self.name}/correct_target",
                             CorrectTarget.Request(target=target_msg(self.cell["targets"][0])),
                             30)

    def test_a_request_over_the_bound_is_refused_by_the_clients_middleware(self):
        before = self.correct_one()
        assert before.success, before.message
        client = self.ros.client.create_client(CorrectTargets, f"/{self.name}/correct_targets")
        try:
            assert client.wait_for_service(timeout_sec=30)
            request = CorrectTargets.Request(targets=[target_msg(self.cell["targets"][0])]
                                             * (BOUND + 1))
            with pytest.raises(Exception, match="failed to send request"):
                client.call_async(request)
            small = CorrectTargets.Request(targets=[target_msg(t) for t in self.cell["targets"]])
            future = client.call_async(small)
            done = threading.Event()
            future.add_done_callback(lambda _: done.set())
            assert done.wait(30), "no answer to a small request after the refused one"
            answer = future.result()
            assert answer.success, answer.message
            assert len(answer.results) == len(self.cell["targets"])
        finally:
            self.ros.client.destroy_client(client)
        after = self.correct_one()
        assert after.success and after.destination == before.destination

    def test_a_large_request_does_not_hold_up_another_clients_correct_target(self):
        # A second client node (its own DDS endpoints) sends BOUND targets: more than
        # max_targets (10,000), so the node refuses it, after taking it in (several seconds).
        other = self.ros.add(rclpy.create_node("large_client", context=self.ros.context))
        client = other.create_client(CorrectTargets, f"/{self.name}/correct_targets")
        try:
            assert client.wait_for_service(timeout_sec=30)
            assert self.correct_one().success
            request = CorrectTargets.Request(targets=[PointStamped()] * BOUND)
            answered = threading.Event()
            sent = threading.Event()

            def send():
                future = client.call_async(request)
                sent.set()
                future.add_done_callback(lambda _: answered.set())
                self.large_answer = future

            thread = threading.Thread(target=send)
            thread.start()
            sent.wait(60)
            during = []
            while not answered.is_set():
                response = self.correct_one()
                if not answered.is_set():
                    during.append(response.success)
                time.sleep(0.02)
            thread.join()
            large = self.large_answer.result()
            assert not large.success and "max_targets" in large.message
            # One after the other, each answered while the large request was still in the node.
            assert len(during) >= 5, f"only {len(during)} answers during the large request"
            assert all(during)
        finally:
            self.ros.remove(other)
