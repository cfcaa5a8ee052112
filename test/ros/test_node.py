"""registration_node in process: real rclpy, its own Context per test class, a client node in the
same executor. Answers are compared with the core library on the same data."""

import itertools
import json
import os

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("rbc_registration_interfaces.msg")

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from geometry_msgs.msg import PointStamped, TransformStamped  # noqa: E402
from rcl_interfaces.msg import ParameterType  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from visualization_msgs.msg import Marker, MarkerArray  # noqa: E402

from rbc_registration.ros.conversions import transform_to_matrix  # noqa: E402
from rbc_registration.ros.node import RegistrationNode  # noqa: E402
from rbc_registration.ros.services import rebuild_requested_ns  # noqa: E402
from rbc_registration_interfaces.msg import FiducialPair, RegistrationStatus  # noqa: E402
from rbc_registration_interfaces.srv import (CorrectTarget, CorrectTargets,  # noqa: E402
                                             GetFiducials, SetFiducialEnabled)

from rbc_registration.pipeline.state import build_state  # noqa: E402
from ros_helpers import (RosTestBase, answer_key, expected_state, make_cell,  # noqa: E402
                         pair_msg, point_xyz, target_msg, wait_for)

pytestmark = pytest.mark.ros
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
_names = itertools.count()


class NodeTestBase(RosTestBase):
    """One Context per test class; each test makes its own node(s) with unique names."""

    @classmethod
    def setup_class(cls):
        super().setup_class()
        cls.cell = make_cell()
        cls.n = len(cls.cell["fid"])

    def setup_method(self):
        self.nodes = []

    def teardown_method(self):
        for node in self.nodes:
            self.ros.remove(node)

    def make_node(self, node_options=None, **params):
        """A node with parameters ``params``; ``node_options`` go to the constructor."""
        name = f"reg_{os.getpid()}_{next(_names)}"
        params = {"debounce_period": 0.05, "state_dir": "", **params}  # no persistence unless given
        overrides = [Parameter(k, value=v) for k, v in params.items()]
        node = RegistrationNode(name, context=self.ros.context, parameter_overrides=overrides,
                                **(node_options or {}))
        self.nodes.append(self.ros.add(node))
        return node

    def publisher(self, node, msg_type, topic):
        pub = self.ros.client.create_publisher(msg_type, f"/{node.get_name()}/{topic}", 1000)
        wait_for(lambda: pub.get_subscription_count() > 0, what=f"subscriber of {topic}")
        return pub

    def stream(self, node, indices=None, with_ids=True, wait=True, stamp_offset=0.0):
        """Publish measurements ``indices`` of the cell, measurement k stamped 100 s + k +
        ``stamp_offset`` (the same stamps and points again would be duplicates, rejected)."""
        pub = self.publisher(node, FiducialPair, "fiducial_pairs")
        indices = range(self.n) if indices is None else indices
        before = node.status().n_measurements
        for k in indices:
            pub.publish(pair_msg(self.cell, k, with_id=with_ids,
                                 stamp_s=100.0 + k + stamp_offset))
        if wait:
            wait_for(lambda: node.status().n_measurements == before + len(indices),
                     what="measurements accepted")
        self.ros.client.destroy_publisher(pub)

    def srv(self, node, srv_type, name, request=None):
        return self.ros.call(srv_type, f"/{node.get_name()}/{name}",
                             request if request is not None else srv_type.Request())

    def recompute(self, node):
        """~/recompute answers at once; wait as msg_docs tells a user to: for a ~/status whose
        last_recompute is at or after the time the answer names. The node publishes that status
        after the rebuild's transforms, /tf_static and markers (a CI failure: waiting for the
        served model instead, a late joiner got the /tf_static of the model before)."""
        response = self.srv(node, Trigger, "recompute")
        assert response.success, response.message
        requested = rebuild_requested_ns(response.message)
        self.latest(node, RegistrationStatus, f"/{node.get_name()}/status",
                    predicate=lambda m: (m.last_recompute.sec * 10**9
                                         + m.last_recompute.nanosec) >= requested)
        return node.state

    def correct(self, node, xyz, frame="tracker"):
        return self.srv(node, CorrectTarget, "correct_target",
                        CorrectTarget.Request(target=target_msg(xyz, frame)))

    def latest(self, node, msg_type, topic, qos=LATCHED, predicate=lambda m: True):
        got = []
        sub = self.ros.client.create_subscription(msg_type, topic, got.append, qos)
        try:
            wait_for(lambda: any(predicate(m) for m in got), what=f"a message on {topic}")
            return [m for m in got if predicate(m)][-1]
        finally:
            self.ros.client.destroy_subscription(sub)

    def assert_answers_match_core(self, node, expected, targets):
        tc = expected.model.correct(targets)
        for k, target in enumerate(targets):
            r = self.correct(node, target)
            assert r.success, r.message
            np.testing.assert_allclose(point_xyz(r.corrected.point), tc.corrected[k], atol=1e-12)
            np.testing.assert_allclose(point_xyz(r.uncorrected.point), tc.uncorrected[k],
                                       atol=1e-12)
            np.testing.assert_allclose(point_xyz(r.correction), tc.correction[k], atol=1e-12)
            assert r.inside_hull == bool(tc.inside_hull[k])


class TestLiveRegistration(NodeTestBase):

    def test_fiducial_pairs_give_the_core_model_and_answers(self):
        node = self.make_node()
        self.stream(node)
        state = self.recompute(node)
        expected = expected_state(self.cell, debounce_period=0.05)
        assert state.model.ids == expected.model.ids
        np.testing.assert_array_equal(state.model.corrections, expected.model.corrections)
        self.assert_answers_match_core(node, expected, self.cell["targets"])
        r = self.correct(node, self.cell["targets"][0])
        decision = expected.model.decision
        tc0 = expected.model.correct(self.cell["targets"][:1])
        assert r.correction_applied and decision.apply and r.method == decision.method
        np.testing.assert_allclose(point_xyz(r.destination.point), tc0.destination[0], atol=1e-12)
        assert r.expected_tre == pytest.approx(tc0.expected_tre[0], rel=1e-9)
        assert r.tre_bound == pytest.approx(tc0.tre_bound[0], rel=1e-9) and r.tre_bound > 0
        assert r.destination.header.frame_id == "world"
        assert r.message.startswith(f"{decision.method}: corrections applied (decision cv)")
        assert decision.reason in r.message

        batch = self.srv(node, CorrectTargets, "correct_targets", CorrectTargets.Request(
            targets=[target_msg(t) for t in self.cell["targets"]]))
        assert batch.success and len(batch.results) == len(self.cell["targets"])
        tc = expected.model.correct(self.cell["targets"])
        np.testing.assert_allclose([point_xyz(x.destination.point) for x in batch.results],
                                   tc.destination, atol=1e-12)
        np.testing.assert_allclose([x.expected_tre for x in batch.results], tc.expected_tre,
                                   rtol=1e-9)
        assert {x.method for x in batch.results} == {decision.method}
        assert decision.reason in batch.message

        status = self.latest(node, RegistrationStatus, f"/{node.get_name()}/status",
                             predicate=lambda m: m.model_valid)
        assert (status.n_fiducials, status.n_measurements, status.n_rejected) == (48, 144, 0)
        assert status.sigma_source == "repeats" and status.recommendation == "apply"
        assert status.corrections_applied and status.fre_rms_corrected < 1e-9
        assert len(status.sigma_l) == 3 and status.rho == pytest.approx(expected.model.rho)
        assert status.sigma_axis == pytest.approx(expected.model.sigma_axis, rel=1e-12)
        assert (status.decision_mode, status.decision_method, status.decision_reason,
                status.decision_confident) == ("cv", decision.method, decision.reason, True)
        chosen = decision.candidate(decision.method)
        assert status.expected_tre_median == pytest.approx(chosen.cv_median, rel=1e-12)
        assert status.expected_tre_bound == pytest.approx(chosen.cv_bound, rel=1e-12)
        assert list(status.cv_methods) == [c.method for c in decision.candidates]
        np.testing.assert_allclose(status.cv_median, [c.cv_median for c in decision.candidates],
                                   rtol=1e-12)

    def test_transforms_are_latched_for_late_joiners(self):
        node = self.make_node()
        self.stream(node)
        model = self.recompute(node).model
        for topic, registration in (("transform", model.corrected),
                                    ("transform_uncorrected", model.uncorrected)):
            msg = self.latest(node, TransformStamped, f"/{node.get_name()}/{topic}")
            assert msg.header.frame_id == "world" and msg.child_frame_id == "tracker"
            m = transform_to_matrix(msg)
            np.testing.assert_allclose(m[:3, :3], registration.rotation, atol=1e-12)
            np.testing.assert_allclose(m[:3, 3], registration.translation, atol=1e-12)

    def test_markers_and_diagnostics(self):
        node = self.make_node()
        self.stream(node)
        self.recompute(node)
        markers = self.latest(node, MarkerArray, f"/{node.get_name()}/markers",
                              predicate=lambda m: len(m.markers) > 2)
        kinds = [m.type for m in markers.markers[1:]]
        assert markers.markers[0].action == Marker.DELETEALL
        assert kinds.count(Marker.SPHERE_LIST) == 1 and kinds.count(Marker.ARROW) == 48
        arrow = [m for m in markers.markers if m.ns.endswith("corrections")][0]
        length = np.linalg.norm(point_xyz(arrow.points[1]) - point_xyz(arrow.points[0]))
        assert length > 0.01   # ~1 mm corrections drawn 100x longer: visible
        name = f"{node.get_fully_qualified_name()}: registration"   # /<name>: registration
        diag = self.latest(node, DiagnosticArray, "/diagnostics", qos=10, predicate=lambda m: any(
            s.name == name for s in m.status))
        status = [s for s in diag.status if s.name == name][0]
        assert status.level == DiagnosticStatus.OK, status.message

    def test_points_paired_by_stamp_get_ids_by_proximity(self):
        node = self.make_node()
        w_pub = self.publisher(node, PointStamped, "working_point")
        d_pub = self.publisher(node, PointStamped, "destination_point")
        for k in range(self.n):
            stamp = 10.0 + 0.1 * k
            for pub, frame, xyz, offset in ((w_pub, "tracker", self.cell["working"][k], 0.0),
                                            (d_pub, "world", self.cell["destination"][k], 0.004)):
                msg = target_msg(xyz, frame)
                t = stamp + offset
                msg.header.stamp.sec, msg.header.stamp.nanosec = int(t), int(t % 1 * 1e9)
                pub.publish(msg)
        wait_for(lambda: node.status().n_measurements == self.n, what="pairs")
        state = self.recompute(node)
        expected = expected_state(self.cell, with_ids=False)
        assert len(state.model.ids) == 48 and state.model.ids[0] == "auto-0000"
        assert all(n == 3 for n in state.fiducials.repeat_stats.counts)  # visits merged
        self.assert_answers_match_core(node, expected, self.cell["targets"][:3])

    def test_no_model_until_enough_fiducials(self):
        node = self.make_node(min_fiducials=10)
        r = self.correct(node, [0.1, 0.2, 0.3])
        assert not r.success and r.message.startswith("no model yet")
        self.stream(node, range(5))
        assert self.recompute(node).model is None
        r = self.correct(node, [0.1, 0.2, 0.3])
        assert not r.success and "5 enabled fiducials, need min_fiducials=10" in r.message

    def test_a_burst_is_debounced(self):
        builds = []

        def counting_build(*args):
            builds.append(1)
            return build_state(*args)

        node = self.make_node(debounce_period=0.5, node_options={"build": counting_build})
        self.stream(node)
        wait_for(lambda: node.state.model is not None, what="debounced model")
        assert len(builds) <= 3   # not one per message (144 messages)
        assert node.status().n_pending == 0

    def test_a_shorter_debounce_period_applies_to_the_pending_batch(self):
        """with debounce_period 30 s and one pair pending, setting 0.05 s still left
        the pair out of the model for 28 s (the sleeping thread was not woken)."""
        node = self.make_node(debounce_period=30.0)
        self.stream(node)
        assert node.state.model is None and node.status().n_pending == len(self.cell["fid"])
        assert node.set_parameters([Parameter("debounce_period", value=0.05)])[0].successful
        # before the fix it came after the old period (28 s), well beyond this wait
        wait_for(lambda: node.state.model is not None, timeout=20.0, what="the pending batch")
        assert node.status().n_pending == 0


class TestRebuildWorker(NodeTestBase):
    """rebuild_worker: a build in the child process serves what the thread's would; the node's
    shutdown kills the child and does not wait for its build."""

    def test_a_model_built_in_the_process_answers_as_the_core_and_a_switch_to_thread_too(self):
        node = self.make_node(rebuild_worker="process", interpolation="kriging")
        self.stream(node)
        state = self.recompute(node)
        builder = node._builder
        assert builder.n_started == 1 and builder.child_pid is not None
        expected = expected_state(self.cell, debounce_period=0.05, interpolation="kriging",
                                  rebuild_worker="process")
        np.testing.assert_array_equal(state.model.corrections, expected.model.corrections)
        self.assert_answers_match_core(node, expected, self.cell["targets"])
        assert node.set_parameters([Parameter("rebuild_worker", value="thread")])[0].successful
        self.recompute(node)
        assert builder.n_started == 1
        self.assert_answers_match_core(node, expected, self.cell["targets"])

    def test_a_killed_build_process_is_replaced_and_the_node_keeps_serving(self):
        node = self.make_node(rebuild_worker="process")
        self.stream(node)
        self.recompute(node)
        os.kill(node._builder.child_pid, 9)
        assert self.correct(node, self.cell["targets"][0]).success   # the served model
        self.recompute(node)                                         # a new child builds it
        assert node._builder.n_started == 2
        self.assert_answers_match_core(node, expected_state(self.cell, debounce_period=0.05),
                                       self.cell["targets"])

    def test_destroying_the_node_kills_the_build_process(self):
        node = self.make_node(rebuild_worker="process")
        self.stream(node)
        self.recompute(node)
        child = node._builder._child.process
        self.nodes.remove(node)
        self.ros.remove(node)
        assert child.poll() is not None


class TestBadInput(NodeTestBase):

    def test_each_rejection_is_counted_and_the_node_keeps_answering(self):
        node = self.make_node(outlier_distance=0.002)
        self.stream(node)
        before = self.recompute(node).model
        target = self.cell["targets"][0]
        good = self.correct(node, target)
        pub = self.publisher(node, FiducialPair, "fiducial_pairs")
        bad_frame = pair_msg(self.cell, 0, frame="camera")
        bad_dest_frame = pair_msg(self.cell, 0, destination_frame="map")
        nan = pair_msg(self.cell, 1)
        nan.working_point.y = float("nan")
        inf = pair_msg(self.cell, 1)
        inf.destination_point.z = float("inf")
        outlier = pair_msg(self.cell, 2)
        outlier.working_point.x += 0.01
        malformed = pair_msg(self.cell, 3)
        malformed.fiducial_id = "H03\nH04"
        for msg in (bad_frame, bad_dest_frame, nan, inf, outlier, malformed):
            pub.publish(msg)
        # Unpairable points: a working point whose destination never comes is dropped once the
        # destination stream has moved past it.
        w_pub = self.publisher(node, PointStamped, "working_point")
        d_pub = self.publisher(node, PointStamped, "destination_point")
        lonely = target_msg([0, 0, 0], "tracker")
        lonely.header.stamp.sec = 5
        w_pub.publish(lonely)
        wait_for(lambda: node.status().n_rejected == 6, what="6 rejections")
        later = target_msg([0, 0, 0], "world")
        later.header.stamp.sec = 9
        d_pub.publish(later)
        wait_for(lambda: node.status().n_rejected == 7, what="the unpaired point")
        s = node.status()
        assert (s.n_rejected_frame, s.n_rejected_nonfinite, s.n_rejected_outlier,
                s.n_rejected_malformed) == (2, 2, 1, 2)
        assert s.n_measurements == self.n   # nothing rejected reached the model
        after = self.recompute(node).model
        np.testing.assert_array_equal(after.corrections, before.corrections)
        assert answer_key(self.correct(node, target)) == answer_key(good)

    def test_a_wild_new_fiducial_is_left_out_named_and_the_node_keeps_its_model(self):
        """one new pair with a mistyped coordinate (1e7 m) made every later
        ~/correct_target answer 'no model yet: model not built: fiducials are coplanar'."""
        node = self.make_node()
        self.stream(node)
        before = self.recompute(node)
        pub = self.publisher(node, FiducialPair, "fiducial_pairs")
        wild = {"ids": np.array(["typo"]), "fid": np.array([0]),
                "working": np.array([[1e7, 0.2, 0.3]]), "destination": np.array([[0.4, 0.5, 0.6]])}
        pub.publish(pair_msg(wild, 0, stamp_s=500.0))
        wait_for(lambda: node.status().n_measurements == len(self.cell["fid"]) + 1,
                 what="the wild pair accepted")
        state = self.recompute(node)
        assert state.model is not None and state.fiducials.left_out_ids == ("typo",)
        status = node.status()
        assert status.model_valid and status.n_fiducials == before.model.ids.__len__()
        assert status.message.startswith("fiducial 'typo' (1e+07 m): distances to the other")
        listed = self.srv(node, GetFiducials, "get_fiducials")
        typo = [f for f in listed.fiducials if f.fiducial_id == "typo"]
        assert listed.success and len(typo) == 1 and typo[0].enabled
        assert np.isnan([typo[0].correction_norm, typo[0].cv_error]).all()
        self.assert_answers_match_core(node, expected_state(self.cell, debounce_period=0.05),
                                       self.cell["targets"])

    def test_bad_targets_get_a_reason_and_nothing_breaks(self):
        node = self.make_node()
        self.stream(node)
        self.recompute(node)
        r = self.correct(node, [0.1, 0.2, 0.3], frame="camera")
        assert not r.success and "frame_id 'camera'" in r.message
        r = self.correct(node, [0.1, float("nan"), 0.3])
        assert not r.success and "NaN" in r.message
        batch = self.srv(node, CorrectTargets, "correct_targets", CorrectTargets.Request(
            targets=[target_msg([0.1, 0.2, 0.3]), target_msg([0, 0, 0], "camera")]))
        assert not batch.success and "target 1" in batch.message and not batch.results
        assert self.srv(node, CorrectTargets, "correct_targets").success   # empty list
        assert self.correct(node, self.cell["targets"][0]).success

    def test_parameter_updates_are_validated_with_a_reason(self):
        node = self.make_node()
        results = node.set_parameters([Parameter("rho_reject", value=5.0)])
        assert not results[0].successful and "must be <= rho_apply" in results[0].reason
        results = node.set_parameters([Parameter("pair_slop", value=0.0)])
        assert not results[0].successful and "pair_slop" in results[0].reason
        results = node.set_parameters([Parameter("interpolation", value="cubic")])
        assert not results[0].successful and "one of paper, kriging" in results[0].reason
        results = node.set_parameters([Parameter("dimension", value=2)])
        assert not results[0].successful   # read-only
        results = node.set_parameters([Parameter("sigma", value=1)])   # integer for a double
        assert not results[0].successful
        assert node.set_parameters([Parameter("merge_radius", value=0.01)])[0].successful
        assert node.get_parameter("merge_radius").value == 0.01
        desc = node.describe_parameter("merge_radius")
        assert desc.type == ParameterType.PARAMETER_DOUBLE and desc.floating_point_range

    def test_decision_modes(self):
        node = self.make_node()
        self.stream(node)
        self.recompute(node)
        target = self.cell["targets"][1]
        for mode, applied in (("off", False), ("on", True), ("cv", True)):
            assert node.set_parameters([Parameter("decision", value=mode)])[0].successful
            state = self.recompute(node)
            assert state.model.decision.mode.value == mode
            r = self.correct(node, target)
            assert r.correction_applied is applied and f"(decision {mode})" in r.message
            assert r.method == state.model.decision.method
            if mode != "cv":
                assert r.destination == (r.corrected if applied else r.uncorrected)
        # The paper's rule with a known sigma that makes rho small: not applied.
        assert node.set_parameters([Parameter("decision", value="rho"),
                                    Parameter("sigma", value=0.01)])[0].successful
        state = self.recompute(node)
        assert state.model.recommendation == "do_not_apply"
        r = self.correct(node, target)
        assert r.success and not r.correction_applied and r.method == "uncorrected"
        assert "The paper's rule: rho = " in r.message
        assert node.status().sigma_source == "parameter"
        # sigma_axis in place of sigma: both at once is refused, the same noise gives the same rho.
        both = node.set_parameters([Parameter("sigma_axis", value=0.01)])[0]
        assert not both.successful and "give sigma or sigma_axis, not both" in both.reason
        assert node.set_parameters([Parameter("sigma", value=0.0),
                                    Parameter("sigma_axis", value=0.01 / 3 ** 0.5)])[
            0].successful
        again = self.recompute(node)
        assert again.model.rho == pytest.approx(state.model.rho, rel=1e-12)
        assert node.status().sigma_axis == pytest.approx(0.01 / 3 ** 0.5, rel=1e-12)


class TestServicesAndPersistence(NodeTestBase):

    def test_set_fiducial_enabled(self, tmp_path):
        node = self.make_node(state_dir=str(tmp_path))
        self.stream(node)
        r = self.srv(node, SetFiducialEnabled, "set_fiducial_enabled",
                     SetFiducialEnabled.Request(fiducial_id="H05", enabled=False))
        assert r.success, r.message
        state = self.recompute(node)
        assert "H05" not in state.model.ids and len(state.model.ids) == 47
        assert node.status().n_disabled == 1
        r = self.srv(node, SetFiducialEnabled, "set_fiducial_enabled",
                     SetFiducialEnabled.Request(fiducial_id="nope", enabled=False))
        assert not r.success and "unknown fiducial id 'nope'" in r.message

    def test_restart_rebuilds_the_same_model_from_the_journal(self, tmp_path):
        node = self.make_node(state_dir=str(tmp_path))
        self.stream(node)
        assert self.srv(node, SetFiducialEnabled, "set_fiducial_enabled",
                        SetFiducialEnabled.Request(fiducial_id="H07", enabled=False)).success
        first = self.recompute(node).model
        answers = [answer_key(self.correct(node, t)) for t in self.cell["targets"]]
        self.ros.remove(node)
        self.nodes.remove(node)
        with open(tmp_path / "journal.jsonl", "ab") as f:   # a torn write at the end
            f.write(b'{"t":"m","id":"H01","w":[0.1,')
        again = self.make_node(state_dir=str(tmp_path))
        wait_for(lambda: again.state.model is not None, what="model rebuilt from the journal")
        assert again.state.model.ids == first.ids and "H07" not in first.ids
        np.testing.assert_array_equal(again.state.model.corrections, first.corrections)
        assert [answer_key(self.correct(again, t)) for t in self.cell["targets"]] == answers
        assert again.status().n_measurements == self.n

    def test_save_and_reset(self, tmp_path):
        node = self.make_node(state_dir=str(tmp_path))
        self.stream(node)
        model = self.recompute(node).model
        r = self.srv(node, Trigger, "save")
        assert r.success and "calibration.json" in r.message
        saved = json.loads((tmp_path / "calibration.json").read_text())
        np.testing.assert_allclose(saved["corrected"]["rotation"], model.corrected.rotation)
        assert saved["fiducial_ids"] == list(model.ids) and saved["units"] == "m"
        r = self.srv(node, Trigger, "reset")
        assert r.success and "archived" in r.message
        assert node.status().n_measurements == 0 and not node.status().model_valid
        r = self.correct(node, self.cell["targets"][0])
        assert not r.success and "no model yet" in r.message
        self.stream(node, range(self.n))   # collects again after a reset
        assert self.recompute(node).model is not None

    def test_save_without_state_dir_says_why(self):
        node = self.make_node()
        r = self.srv(node, Trigger, "save")
        assert not r.success and "state_dir is not set" in r.message


class TestTwoDimensions(NodeTestBase):

    def test_x_y_only_and_z_passes_through(self):
        node = self.make_node(dimension=2, min_fiducials=4)
        # 2D: one z layer of the grid (the others have the same x, y).
        layer = [k for k in range(self.n) if self.cell["fid"][k] % 3 == 0]
        self.stream(node, layer)
        state = self.recompute(node)
        expected = expected_state(self.cell, layer, dimension=2, min_fiducials=4)
        assert state.model.working.shape[1] == 2
        target = self.cell["targets"][2]
        r = self.correct(node, target)
        tc = expected.model.correct(target[None, :2])
        assert r.success, r.message
        np.testing.assert_allclose(point_xyz(r.corrected.point)[:2], tc.corrected[0], atol=1e-12)
        assert r.corrected.point.z == target[2] and r.uncorrected.point.z == target[2]
        assert r.correction.z == 0.0
        msg = self.latest(node, TransformStamped, f"/{node.get_name()}/transform")
        m = transform_to_matrix(msg)
        np.testing.assert_allclose(m[:2, :2], state.model.corrected.rotation, atol=1e-12)
        np.testing.assert_allclose(m[2, :], [0, 0, 1, 0], atol=1e-12)

    @pytest.mark.parametrize("z", [float("nan"), float("inf"), -float("inf"), 1e300])
    def test_non_finite_z_of_a_2d_target_is_refused(self, z):
        """issue 11, severe 1: in 2D z passes through, so a NaN/inf z (a tracker that lost the
        beam) must get success=false naming the target and the coordinate, not a NaN answer."""
        node = self.make_node(dimension=2, min_fiducials=4)
        layer = [k for k in range(self.n) if self.cell["fid"][k] % 3 == 0]
        self.stream(node, layer)
        assert self.recompute(node).model is not None
        good = self.cell["targets"][2]
        r = self.correct(node, [good[0], good[1], z])
        assert not r.success
        assert "target 0" in r.message and "z" in r.message, r.message
        batch = self.srv(node, CorrectTargets, "correct_targets", CorrectTargets.Request(
            targets=[target_msg(good), target_msg([good[0], good[1], z])]))
        assert not batch.success and not batch.results
        assert "target 1" in batch.message and "z" in batch.message, batch.message
        assert self.correct(node, good).success


class TestStartAndTf(NodeTestBase):

    def test_bad_starting_parameters_and_a_foreign_journal_are_refused(self, tmp_path):
        with pytest.raises(ValueError, match="rho_reject"):
            RegistrationNode("reg_bad", context=self.ros.context,
                             parameter_overrides=[Parameter("rho_reject", value=5.0)])
        node = self.make_node(state_dir=str(tmp_path))
        self.stream(node, range(3))
        self.ros.remove(node)
        self.nodes.remove(node)
        with pytest.raises(ValueError, match="dimension=3.*dimension=2"):
            RegistrationNode("reg_bad2", context=self.ros.context, parameter_overrides=[
                Parameter("state_dir", value=str(tmp_path)), Parameter("dimension", value=2)])
