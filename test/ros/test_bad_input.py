"""The node rows of the bad-input matrix (docs/HARDENING.md): each bad input gets its reason (the
log line on /rosout, a rejection counter, or the service's ``message``), and afterwards the node
still answers a valid ``~/correct_target`` with the same answer, from the same measurements.

One node serves the whole class: every test must leave it exactly as it found it, so the cases
also show that bad input does not accumulate into harm.
"""

import itertools
import math
import os

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("rbc_registration_interfaces.msg")

from geometry_msgs.msg import PointStamped  # noqa: E402
from rcl_interfaces.msg import Log  # noqa: E402
from rcl_interfaces.srv import SetParameters  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import qos_profile_rosout_default  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from rbc_registration.ros.node import RegistrationNode  # noqa: E402
from rbc_registration.ros.services import rebuild_requested_ns  # noqa: E402
from rbc_registration_interfaces.msg import FiducialPair  # noqa: E402
from rbc_registration_interfaces.srv import (CorrectTarget, CorrectTargets,  # noqa: E402
                                             SetFiducialEnabled)

from ros_helpers import (RosTestBase, answer_key, make_cell, pair_msg, target_msg,  # noqa: E402
                         wait_for)

pytestmark = pytest.mark.ros
MB = 2 ** 20
#: Invalid parameter updates: (test id, parameter, value, the reason's text).
BAD_PARAMETERS = [
    ("restoration-choice", "restoration", "magic",
     "restoration must be one of iterative, closed-form; got 'magic'"),
    ("restoration_steps-range", "restoration_steps", 0,
     "Parameter restoration_steps out of range. Min: 1, Max: 20, value: 0"),
    ("restoration_steps-type", "restoration_steps", 2.5,
     "Wrong parameter type: restoration_steps must be of type integer, got double 2.5"),
    ("interpolation-choice", "interpolation", "cubic",
     "interpolation must be one of paper, kriging; got 'cubic'"),
    ("sigma-range", "sigma", -0.001,
     "Parameter sigma out of range Min: 0.0, Max: 1.0, value: -0.001"),
    ("sigma-nan", "sigma", math.nan, "Parameter sigma out of range"),
    ("sigma-integer", "sigma", 1,
     "Wrong parameter type: sigma must be of type double, got integer 1 (write 1.0)"),
    ("sigma-string", "sigma", "1e-4",
     "Wrong parameter type: sigma must be of type double, got string '1e-4'"),
    ("rho_reject-order", "rho_reject", 3.0, "rho_reject (3) must be <= rho_apply (2.5)"),
    ("rho_apply-order", "rho_apply", 0.5, "rho_reject (1) must be <= rho_apply (0.5)"),
    ("decision-choice", "decision", "auto", "decision must be one of cv, rho, on, off; got 'auto'"),
    ("decision-type", "decision", True,
     "Wrong parameter type: decision must be of type string, got bool True (YAML reads an "
     "unquoted on, off"),
    ("sigma_axis-range", "sigma_axis", -0.001,
     "Parameter sigma_axis out of range Min: 0.0, Max: 1.0, value: -0.001"),
    ("min_fiducials-range", "min_fiducials", 2, "Parameter min_fiducials out of range"),
    ("pair_slop-zero", "pair_slop", 0.0, "pair_slop must be in (0, 10], got 0.0"),
    ("merge_radius-zero", "merge_radius", 0.0, "merge_radius must be in (0, 10], got 0.0"),
    ("outlier_distance-range", "outlier_distance", -1.0,
     "Parameter outlier_distance out of range"),
    ("max_stamp_age-range", "max_stamp_age", -1.0, "Parameter max_stamp_age out of range"),
    ("max_targets-range", "max_targets", 0, "Parameter max_targets out of range"),
    ("debounce_period-range", "debounce_period", 61.0, "Parameter debounce_period out of range"),
    ("tf_broadcast-choice", "tf_broadcast", "both",
     "tf_broadcast must be one of corrected, uncorrected, none; got 'both'"),
    ("use_sim_time-type", "use_sim_time", "true",
     "Wrong parameter type: use_sim_time must be of type bool, got string 'true' (write "
     "use_sim_time:=true or use_sim_time:=false, unquoted)"),
    ("sample_tf_parent-slash", "sample_tf_parent", "/base_link",
     "sample_tf_parent is a tf frame id (or empty): it must not start with '/' (tf2 refuses "
     "it), got '/base_link'"),
    ("sample_tf_child-space", "sample_tf_child", "tool 0",
     "sample_tf_child is a tf frame id (or empty): it must not contain whitespace"),
    ("sample_tf_parent-other", "sample_tf_parent", "base_link",
     "sample_tf_parent must be empty or destination_frame 'world', got 'base_link'"),
    ("sample_tf_child-working", "sample_tf_child", "tracker",
     "sample_tf_child must not be working_frame 'tracker'"),
    ("sample_tf_child-same", "sample_tf_child", "world",
     "sample_tf_child must differ from sample_tf_parent (empty: destination_frame), both are "
     "'world'"),
    ("marker_scale-zero", "marker_scale", 0.0, "marker_scale must be in (0, 10], got 0.0"),
    ("marker_arrow_gain-range", "marker_arrow_gain", -1.0,
     "Parameter marker_arrow_gain out of range"),
    ("dimension-read-only", "dimension", 2, "Trying to set a read-only parameter: dimension."),
    ("working_frame-read-only", "working_frame", "camera",
     "Trying to set a read-only parameter: working_frame."),
    ("state_dir-read-only", "state_dir", "/tmp/elsewhere",
     "Trying to set a read-only parameter: state_dir."),
    ("unknown", "bogus", 1, "Invalid access to undeclared parameter(s): ['bogus']"),
]


class TestNodeBadInput(RosTestBase):

    @classmethod
    def setup_class(cls):
        super().setup_class()
        cls.cell = make_cell()
        cls.n = len(cls.cell["fid"])
        cls.name = f"reg_bad_input_{os.getpid()}"
        cls.node = cls.ros.add(RegistrationNode(cls.name, context=cls.ros.context,
                                                parameter_overrides=[
                                                    Parameter("debounce_period", value=0.05)]))
        cls.logs = []
        cls.ros.client.create_subscription(Log, "/rosout", cls.logs.append,
                                           qos_profile_rosout_default)
        cls.pubs = {}
        pub = cls.publisher(FiducialPair, "fiducial_pairs")
        for k in range(cls.n):
            pub.publish(pair_msg(cls.cell, k, stamp_s=100.0 + k))
        wait_for(lambda: cls.node.status().n_measurements == cls.n, what="all pairs")
        cls.corrections = cls.recompute().model.corrections.copy()
        cls.target = cls.cell["targets"][0]
        cls.good = answer_key(cls.correct_target(cls.target))
        assert cls.good[0], "the valid target is answered"
        cls.stamps = itertools.count(1000)

    @classmethod
    def teardown_class(cls):
        cls.ros.remove(cls.node)
        super().teardown_class()

    # -- helpers ------------------------------------------------------------------------------
    @classmethod
    def publisher(cls, msg_type, topic):
        if topic not in cls.pubs:
            pub = cls.ros.client.create_publisher(msg_type, f"/{cls.name}/{topic}", 1000)
            wait_for(lambda: pub.get_subscription_count() > 0, what=f"subscriber of {topic}")
            cls.pubs[topic] = pub
        return cls.pubs[topic]

    @classmethod
    def srv(cls, srv_type, name, request):
        return cls.ros.call(srv_type, f"/{cls.name}/{name}", request)

    @classmethod
    def correct_target(cls, xyz, frame="tracker"):
        return cls.srv(CorrectTarget, "correct_target",
                       CorrectTarget.Request(target=target_msg(xyz, frame)))

    @classmethod
    def recompute(cls):
        response = cls.srv(Trigger, "recompute", Trigger.Request())
        assert response.success, response.message
        requested = rebuild_requested_ns(response.message)
        wait_for(lambda: cls.node.state.stamp_ns >= requested, what="the requested rebuild")
        return cls.node.state

    def setup_method(self):
        self.before = self.node.status()
        self.n_logs = len(self.logs)

    def rejected(self, reason, count=1):
        """Wait until ``count`` more measurements were rejected for ``reason``."""
        field = f"n_rejected_{reason}"
        want = getattr(self.before, field) + count
        wait_for(lambda: getattr(self.node.status(), field) == want, what=f"{field} == {want}")

    def logged(self, fragment):
        """The node's log line (on /rosout) since this test began that contains ``fragment``."""
        def found():
            return [m.msg for m in self.logs[self.n_logs:]
                    if m.name == self.name and fragment in m.msg]
        wait_for(found, what=f"a log line with {fragment!r}")
        return found()[-1]

    def test_a_misspelt_start_up_parameter_is_warned_about(self):
        """-p decison:="'off'" started the node with the decision cv, without a word."""
        name = f"{self.name}_typo"
        node = self.ros.add(RegistrationNode(name, context=self.ros.context, parameter_overrides=[
            Parameter("decison", value="off"), Parameter("debounce_period", value=0.05)]))
        try:
            def found():
                return [m for m in self.logs[self.n_logs:] if m.name == name
                        and m.level == Log.WARN and "decison (did you mean decision?)" in m.msg]
            wait_for(found, what="the WARN naming the misspelt parameter")
            assert node._settings.decision == "cv"                # ignored, as rclpy does
        finally:
            self.ros.remove(node)

    def assert_unharmed(self, rejected=0):
        """Nothing accepted was lost or added, and a valid target gets the same answer."""
        status = self.node.status()
        assert status.n_measurements == self.before.n_measurements == self.n
        assert status.n_rejected == self.before.n_rejected + rejected
        np.testing.assert_array_equal(self.recompute().model.corrections, self.corrections)
        assert answer_key(self.correct_target(self.target)) == self.good

    def pair(self, k=0, **fields):
        msg = pair_msg(self.cell, k, stamp_s=float(next(self.stamps)))
        for name, value in fields.items():
            obj, attr = (msg, name) if "." not in name else (
                getattr(msg, name.split(".")[0]), name.split(".")[1])
            setattr(obj, attr, value)
        self.publisher(FiducialPair, "fiducial_pairs").publish(msg)

    def point(self, stream, frame, stamp, xyz=(0.1, 0.2, 0.3)):
        msg = target_msg(xyz, frame)
        msg.header.stamp.sec, msg.header.stamp.nanosec = int(stamp), int(stamp % 1 * 1e9)
        self.publisher(PointStamped, f"{stream}_point").publish(msg)

    # -- topics -------------------------------------------------------------------------------
    def test_pair_in_another_working_frame(self):
        self.pair(**{"header.frame_id": "camera"})
        self.rejected("frame")
        assert "working frame must be 'tracker', got 'camera'" in self.logged("rejected")
        self.assert_unharmed(1)

    def test_pair_in_another_destination_frame(self):
        self.pair(destination_frame_id="map")
        self.rejected("frame")
        assert "destination frame must be 'world', got 'map'" in self.logged("rejected")
        self.assert_unharmed(1)

    def test_points_in_another_frame(self):
        stamp = next(self.stamps)
        self.point("working", "camera", stamp)
        self.point("destination", "world", stamp)
        self.rejected("frame")
        assert "working frame must be 'tracker', got 'camera'" in self.logged("rejected")
        self.assert_unharmed(1)

    def test_nan_coordinate(self):
        self.pair(**{"working_point.y": math.nan})
        self.rejected("nonfinite")
        assert "working point has NaN or inf" in self.logged("rejected")
        self.assert_unharmed(1)

    def test_inf_coordinate(self):
        self.pair(**{"destination_point.z": -math.inf})
        self.rejected("nonfinite")
        assert "destination point has NaN or inf" in self.logged("rejected")
        self.assert_unharmed(1)

    def test_1e300_coordinate(self):
        self.pair(**{"working_point.x": 1e300})
        self.rejected("nonfinite")
        assert "working point has a coordinate beyond ±1e+12" in self.logged("rejected")
        self.assert_unharmed(1)

    def test_stale_and_future_stamps(self):
        assert self.node.set_parameters([Parameter("max_stamp_age", value=5.0)])[0].successful
        try:
            now = self.node.get_clock().now().nanoseconds * 1e-9
            self.pair()                      # stamp 1000 s: decades old
            self.rejected("stale")
            assert "s older than the clock" in self.logged("rejected")
            msg = pair_msg(self.cell, 0, stamp_s=now + 3600.0)
            self.publisher(FiducialPair, "fiducial_pairs").publish(msg)
            self.rejected("stale", 2)
            assert "s ahead of the clock" in self.logged("ahead")
            assert "max_stamp_age is 5 s" in self.logged("ahead")
        finally:
            assert self.node.set_parameters([Parameter("max_stamp_age", value=0.0)])[0].successful
        self.assert_unharmed(2)

    def test_a_pair_published_twice_is_one_measurement(self):
        """A topic bridged twice delivers every pair twice: the copy is not a repeat (it would
        halve sigma's degrees of freedom and make rho look better than it is)."""
        for k in (0, 1):
            self.publisher(FiducialPair, "fiducial_pairs").publish(
                pair_msg(self.cell, k, stamp_s=100.0 + k))
        self.rejected("duplicate", 2)
        line = self.logged("'H01' at stamp 101.000000000 s")
        assert line.startswith("rejected measurement (duplicate, ")
        assert "at stamp 101.000000000 s: the same points as an accepted measurement" in line
        self.assert_unharmed(2)

    def test_one_stamp_with_other_points_is_a_conflict(self):
        msg = pair_msg(self.cell, 2, stamp_s=102.0)
        msg.working_point.x += 1e-3
        self.publisher(FiducialPair, "fiducial_pairs").publish(msg)
        self.rejected("conflict")
        assert "other points than an accepted measurement with that stamp" in \
            self.logged("conflict")
        self.assert_unharmed(1)

    def test_a_stamp_with_nanosec_of_a_second_or_more_is_malformed(self):
        """builtin_interfaces/Time.nanosec is below 1e9: 4e9 is not 'four seconds later' (the
        pair would be taken at another time than the sensor's), it is a broken stamp."""
        msg = pair_msg(self.cell, 3, stamp_s=103.0)
        msg.header.stamp.nanosec = 4_000_000_000
        self.publisher(FiducialPair, "fiducial_pairs").publish(msg)
        self.rejected("malformed")
        assert ("header.stamp.nanosec must be below 10^9 (a builtin_interfaces/Time), got "
                "4000000000") in self.logged("nanosec")
        self.assert_unharmed(1)

    def test_1mb_fiducial_id(self):
        self.pair(fiducial_id="H" * MB)
        self.rejected("malformed")
        line = self.logged("rejected")
        assert "fiducial_id must be at most 256 characters" in line
        assert "(1048576 characters)" in line and len(line) < 400
        self.assert_unharmed(1)

    def test_fiducial_id_with_a_line_break(self):
        self.pair(fiducial_id="H01\nH02")
        self.rejected("malformed")
        assert "without line breaks, got 'H01\\nH02'" in self.logged("rejected")
        self.assert_unharmed(1)

    def test_1mb_frame_id(self):
        self.pair(**{"header.frame_id": "f" * MB})
        self.rejected("frame")
        line = self.logged("rejected")
        assert "working frame must be 'tracker'" in line and len(line) < 400
        self.assert_unharmed(1)

    def test_unpairable_point(self):
        stamp = next(self.stamps)
        self.point("working", "tracker", stamp)          # its destination point never comes
        self.point("destination", "world", stamp + 1.0)  # the destination stream moves past it
        self.rejected("malformed")
        assert ("unpaired working point dropped: no destination point within 0.02 s"
                in self.logged("unpaired"))
        # Leave no point buffered for the next test: pair the waiting destination point with a
        # working point in another frame (rejected as frame).
        self.point("working", "camera", stamp + 1.0)
        self.rejected("frame")
        self.assert_unharmed(2)

    # -- services -----------------------------------------------------------------------------
    def test_unknown_fiducial_id_to_enable(self):
        r = self.srv(SetFiducialEnabled, "set_fiducial_enabled",
                     SetFiducialEnabled.Request(fiducial_id="nope", enabled=False))
        assert not r.success
        assert r.message.startswith("unknown fiducial id 'nope' (known: 'H00', 'H01', 'H02',")
        r = self.srv(SetFiducialEnabled, "set_fiducial_enabled",
                     SetFiducialEnabled.Request(fiducial_id="x" * MB, enabled=False))
        assert not r.success and "(1048576 characters)" in r.message and len(r.message) < 300
        assert self.node.status().n_disabled == 0
        self.assert_unharmed()

    def test_target_in_another_frame(self):
        r = self.correct_target(self.target, frame="camera")
        assert not r.success
        assert r.message == ("target 0 has frame_id 'camera', expected the working frame "
                             "'tracker' (or empty)")
        r = self.correct_target(self.target, frame="c" * MB)
        assert not r.success and len(r.message) < 300
        self.assert_unharmed()

    @pytest.mark.parametrize("xyz, message", [
        pytest.param([0.1, math.nan, 0.3], "targets contains NaN or inf (first at row 0: "
                                           "[0.1, nan, 0.3])", id="nan"),
        pytest.param([0.1, 0.2, math.inf], "targets contains NaN or inf", id="inf"),
        pytest.param([1e300, 0.2, 0.3], "targets has a coordinate beyond ±1e+12 at row 0",
                     id="1e300"),
    ])
    def test_bad_target_coordinates(self, xyz, message):
        r = self.correct_target(xyz)
        assert not r.success and message in r.message
        self.assert_unharmed()

    def test_targets_in_millimetres_get_a_unit_mismatch_warning(self):
        """Issue 11: a batch in mm against a model in m (every target out of the hull, ~1000x
        off): answered (success), and the message and the log name the likely unit mismatch."""
        mm = [target_msg([1000.0 * v for v in t]) for t in self.cell["targets"][:5]]
        r = self.srv(CorrectTargets, "correct_targets", CorrectTargets.Request(targets=mm))
        assert r.success and len(r.results) == 5
        assert "warning: all 5 targets are outside the fiducials' hull" in r.message
        assert "unit mismatch" in self.logged("likely a unit mismatch")
        ok = self.srv(CorrectTargets, "correct_targets", CorrectTargets.Request(
            targets=[target_msg(t) for t in self.cell["targets"][:5]]))
        assert ok.success and "warning" not in ok.message
        self.assert_unharmed()

    def test_one_bad_target_in_a_batch(self):
        r = self.srv(CorrectTargets, "correct_targets", CorrectTargets.Request(
            targets=[target_msg(self.target), target_msg([0.1, math.nan, 0.3])]))
        assert not r.success and not r.results
        assert r.message.startswith("targets contains NaN or inf (first at row 1")
        self.assert_unharmed()

    def test_too_many_targets(self):
        r = self.srv(CorrectTargets, "correct_targets", CorrectTargets.Request(
            targets=[target_msg(self.target)] * 10_001))
        assert not r.success and not r.results
        assert r.message == ("10001 targets in one request, more than max_targets (10000): "
                             "split the request")
        assert self.node.set_parameters([Parameter("max_targets", value=2)])[0].successful
        try:
            three = CorrectTargets.Request(targets=[target_msg(self.target)] * 3)
            assert "more than max_targets (2)" in self.srv(CorrectTargets, "correct_targets",
                                                           three).message
            three.targets = three.targets[:2]
            assert self.srv(CorrectTargets, "correct_targets", three).success
        finally:
            assert self.node.set_parameters([Parameter("max_targets", value=10_000)])[0]\
                .successful
        self.assert_unharmed()

    # -- parameters ---------------------------------------------------------------------------
    @pytest.mark.parametrize("name, value, reason",
                             [pytest.param(*case[1:], id=case[0]) for case in BAD_PARAMETERS])
    def test_invalid_parameter_update(self, name, value, reason):
        """Through the node's ``set_parameters`` service, as ``ros2 param set`` does it."""
        old = self.node.get_parameter(name).value if self.node.has_parameter(name) else None
        settings = self.node._settings
        r = self.srv(SetParameters, "set_parameters", SetParameters.Request(
            parameters=[Parameter(name, value=value).to_parameter_msg()]))
        assert not r.results[0].successful
        assert reason in r.results[0].reason, r.results[0].reason
        if old is not None:
            assert self.node.get_parameter(name).value == old   # the old value is kept
        assert self.node._settings is settings                  # and so are the settings
        self.assert_unharmed()
