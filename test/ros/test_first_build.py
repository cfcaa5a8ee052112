"""Until the first model exists the node says why: being built, or the first build failed
(after a restart from a large journal every answer said "no
measurements yet" with 17,331 restored, and a first build that failed said so for good)."""

import threading

import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("rbc_registration_interfaces.msg")

from rclpy.parameter import Parameter  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from rbc_registration.pipeline.state import build_state  # noqa: E402
from rbc_registration.ros.node import RegistrationNode  # noqa: E402
from rbc_registration_interfaces.msg import FiducialPair  # noqa: E402
from rbc_registration_interfaces.srv import CorrectTarget  # noqa: E402
from ros_helpers import RosTestBase, make_cell, pair_msg, target_msg, wait_for  # noqa: E402

pytestmark = pytest.mark.ros


class TestTheFirstBuild(RosTestBase):

    def test_the_answers_say_the_model_is_being_built_then_why_it_failed(self):
        release, calls = threading.Event(), []

        def build(*args):
            calls.append(len(calls))
            if len(calls) == 1:                  # the first build: held, then it fails
                assert release.wait(30)
                raise RuntimeError("the build process was killed")
            return build_state(*args)

        name = "rbc_first_build"
        node = self.ros.add(RegistrationNode(name, context=self.ros.context, build=build,
                                             parameter_overrides=[
                                                 Parameter("debounce_period", value=0.05)]))
        try:
            cell = make_cell(seed=1, repeats=1)
            n = len(cell["fid"])
            assert node.status().message.startswith("no measurements yet")
            pub = self.ros.client.create_publisher(FiducialPair, f"/{name}/fiducial_pairs", 100)
            wait_for(lambda: pub.get_subscription_count() > 0, what="the node's subscription")
            for k in range(n):
                pub.publish(pair_msg(cell, k, stamp_s=100.0 + k))
            wait_for(lambda: node.status().n_measurements == n and calls, what="the first build")

            def answer():
                return self.ros.call(CorrectTarget, f"/{name}/correct_target",
                                     CorrectTarget.Request(target=target_msg(cell["targets"][0])))

            building = answer()
            assert not building.success
            assert building.message == ("no model yet: the first model is being built from the "
                                        "accepted measurements: retry in a moment")
            assert node.status().message.startswith("the first model is being built")
            release.set()
            wait_for(lambda: "could not be built" in node.status().message, what="the failure")
            failed = answer()
            assert not failed.success
            assert failed.message == (
                "no model yet: the first model could not be built (RuntimeError: the build "
                "process was killed); the measurements are kept: call ~/recompute to retry")
            assert node.status().n_measurements == n              # nothing forgotten
            assert self.ros.call(Trigger, f"/{name}/recompute", Trigger.Request()).success
            wait_for(lambda: node.status().model_valid, what="the model after ~/recompute")
            assert answer().success
        finally:
            release.set()
            self.ros.remove(node)
