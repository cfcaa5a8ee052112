"""``~/take_sample``: one fiducial recorded from the latest ~/working_point and
~/destination_point (in-process, topic source), through the same validation and journal as every
measurement; missing, stale and rejected points answered success=false naming which; the tf
source refused without tf2_ros, and taken from a tf lookup where tf2_ros is installed."""

import json

import numpy as np
import pytest

pytest.importorskip("rclpy")

from geometry_msgs.msg import PointStamped  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from rbc_registration.ros import samples  # noqa: E402
from rbc_registration.ros.node import RegistrationNode  # noqa: E402
from rbc_registration_interfaces.srv import TakeSample  # noqa: E402
from ros_helpers import point_xyz, wait_for  # noqa: E402
from test_node import NodeTestBase  # noqa: E402

pytestmark = pytest.mark.ros


def _point(xyz, frame):
    msg = PointStamped()
    msg.header.frame_id = frame
    msg.point.x, msg.point.y, msg.point.z = (float(v) for v in xyz)
    return msg


class TestTakeSample(NodeTestBase):

    def send(self, node, topic, xyz, frame, stamp=0.0):
        """Publish one point (streaming drivers publish continuously; one is enough here)."""
        pub = self.publisher(node, PointStamped, topic)
        before = node._samples._latest.get(topic.split("_")[0])
        msg = _point(xyz, frame)
        msg.header.stamp.sec = int(stamp)
        pub.publish(msg)
        wait_for(lambda: node._samples._latest.get(topic.split("_")[0]) is not before,
                 what=f"{topic} received")
        self.ros.client.destroy_publisher(pub)

    def take(self, node, fiducial_id=""):
        return self.srv(node, TakeSample, "take_sample",
                        TakeSample.Request(fiducial_id=fiducial_id))

    def test_records_the_latest_points_through_the_journal(self, tmp_path):
        node = self.make_node(state_dir=str(tmp_path), point_mode="sample", sample_max_age=60.0)
        r = self.take(node, "H00")
        assert not r.success and "no ~/working_point received yet" in r.message
        assert "no ~/destination_point received yet" in r.message
        cell = self.cell
        self.send(node, "working_point", cell["working"][0], "tracker")
        r = self.take(node, "H00")
        assert not r.success and "no ~/destination_point received yet" in r.message
        assert "working_point" not in r.message
        self.send(node, "destination_point", cell["destination"][0], "world")
        assert node.status().n_measurements == 0  # point_mode sample: no stamp pairing
        r = self.take(node, "H00")
        assert r.success, r.message
        assert r.pair.fiducial_id == "H00" and r.pair.header.frame_id == "tracker"
        np.testing.assert_array_equal(point_xyz(r.pair.working_point), cell["working"][0])
        np.testing.assert_array_equal(point_xyz(r.pair.destination_point),
                                      cell["destination"][0])
        assert node.status().n_measurements == 1
        record = json.loads((tmp_path / "journal.jsonl").read_text().splitlines()[-1])
        assert "H00" in json.dumps(record)
        # The same latest working point again would be a false repeat (zero scatter: sigma 0,
        # rho inf): refused, with or without an id, until a new point arrives.
        for fiducial_id in ("H00", ""):
            r = self.take(node, fiducial_id)
            assert not r.success and "recorded already, by the previous ~/take_sample" in \
                r.message and "measure the hole again" in r.message, r.message
        assert node.status().n_measurements == 1
        # A new measurement of the hole (a new message; the destination point kept): a repeat
        # of H00 (n = 2 gives sigma), then once more by proximity.
        self.send(node, "working_point", cell["working"][0] + 1e-5, "tracker")
        assert self.take(node, "H00").success
        self.send(node, "working_point", cell["working"][0] - 1e-5, "tracker")
        r = self.take(node)
        assert r.success and r.pair.fiducial_id == "H00" and "proximity" in r.message
        assert node.status().n_measurements == 3

        # A point in the wrong frame goes through the same validation: rejected as 'frame'.
        self.send(node, "working_point", cell["working"][1], "laser")
        r = self.take(node, "H01")
        assert not r.success and "rejected (frame)" in r.message and "'laser'" in r.message
        assert node.status().n_rejected_frame == 1 and node.status().n_measurements == 3

    def test_a_point_whose_stamp_is_not_a_time_is_rejected_and_counted(self):
        """a latest point with nanosec >= 1e9 answered "rejected (malformed)" but was
        not counted in n_rejected_malformed, as every other rejected measurement is."""
        node = self.make_node(point_mode="sample", sample_max_age=60.0)
        self.send(node, "destination_point", self.cell["destination"][0], "world")
        pub = self.publisher(node, PointStamped, "working_point")
        msg = _point(self.cell["working"][0], "tracker")
        msg.header.stamp.nanosec = 2_000_000_000
        pub.publish(msg)
        wait_for(lambda: node._samples._latest.get("working") is not None, what="received")
        self.ros.client.destroy_publisher(pub)
        r = self.take(node, "H00")
        assert not r.success and "rejected (malformed)" in r.message
        assert "header.stamp.nanosec must be below 10^9" in r.message
        assert node.status().n_rejected_malformed == 1 and node.status().n_measurements == 0
        self.send(node, "working_point", self.cell["working"][0], "tracker")
        assert self.take(node, "H00").success

    def test_a_stale_point_is_named(self):
        node = self.make_node(point_mode="sample", sample_max_age=1e-6)
        self.send(node, "working_point", self.cell["working"][0], "tracker")
        self.send(node, "destination_point", self.cell["destination"][0], "world")
        r = self.take(node, "H00")
        assert not r.success
        assert "the latest ~/working_point is stale" in r.message
        assert "the latest ~/destination_point is stale" in r.message
        assert "more than sample_max_age 1e-06 s" in r.message
        node.set_parameters([Parameter("sample_max_age", value=60.0)])
        assert self.take(node, "H00").success

    def test_pair_mode_still_pairs_by_stamp_and_can_take_samples(self):
        node = self.make_node()  # point_mode pair (default)
        self.send(node, "working_point", self.cell["working"][0], "tracker")
        self.send(node, "destination_point", self.cell["destination"][0], "world")
        wait_for(lambda: node.status().n_measurements == 1, what="the stamp pair")
        # the points of that pair are recorded: a sample of them would be a false repeat
        r = self.take(node, "H05")
        assert not r.success and "recorded already, paired by stamp" in r.message
        assert node.status().n_measurements == 1
        self.send(node, "working_point", self.cell["working"][1], "tracker")   # no partner
        assert self.take(node, "H05").success and node.status().n_measurements == 2

    def test_a_copy_of_a_paired_point_is_a_duplicate_and_not_sampled_again(self):
        """Pair mode, the point topics bridged twice: the copy of a paired working point made
        it the latest point again, unmarked, so ~/take_sample recorded the pair's measurement a
        second time. The pairer drops the copy as a duplicate and the copy keeps the mark.
        Stamped points: an unstamped copy cannot be told from a repeat
        (core/measurements/pairing)."""
        node = self.make_node()
        self.send(node, "working_point", self.cell["working"][0], "tracker", stamp=3.0)
        self.send(node, "destination_point", self.cell["destination"][0], "world", stamp=3.0)
        wait_for(lambda: node.status().n_measurements == 1, what="the stamp pair")
        pub = self.publisher(node, PointStamped, "working_point")
        copy = _point(self.cell["working"][0], "tracker")
        copy.header.stamp.sec = 3
        pub.publish(copy)
        wait_for(lambda: node.status().n_rejected_duplicate == 1, what="the copy refused")
        self.ros.client.destroy_publisher(pub)
        r = self.take(node, "H05")
        assert not r.success and "recorded already, paired by stamp" in r.message, r.message
        assert node.status().n_measurements == 1 and node.status().n_rejected_ambiguous == 0

    def test_a_sampled_point_is_not_recorded_again_by_its_stamp_partner(self):
        """Pair mode: a working point sampled while buffered was recorded again when its
        destination partner arrived (two identical measurements of H1)."""
        node = self.make_node(sample_max_age=60.0)
        self.send(node, "destination_point", self.cell["destination"][0], "world", stamp=1.0)
        self.send(node, "working_point", self.cell["working"][0], "tracker", stamp=5.0)
        assert node._ingest._pairer.pending("working") == 1        # buffered, no partner
        r = self.take(node, "H1")
        assert r.success, r.message
        assert node._ingest._pairer.pending("working") == 0
        self.send(node, "destination_point", self.cell["destination"][0], "world", stamp=5.0)
        wait_for(lambda: node._ingest._pairer.pending("destination") == 1,
                 what="the partner buffered")
        assert node.status().n_measurements == 1

    def test_its_own_points_are_never_counted_as_rejected(self):
        """Pair mode, points stamped far apart (a tracker and a robot measuring one hole a few
        seconds apart): the destination point made the working point stale, and the working
        point sampled next made the destination point stale. Both were counted and logged as
        rejected (malformed) although ~/take_sample recorded them, and /diagnostics said WARN.
        A dropped point nobody samples is still counted, once a newer point of its stream
        arrives."""
        node = self.make_node(sample_max_age=60.0)
        self.send(node, "working_point", self.cell["working"][0], "tracker", stamp=1.0)
        self.send(node, "destination_point", self.cell["destination"][0], "world", stamp=5.0)
        r = self.take(node, "H1")
        assert r.success, r.message
        self.send(node, "working_point", self.cell["working"][0] + 1e-5, "tracker", stamp=9.0)
        r = self.take(node, "H1")      # the same destination point, a new working point
        assert r.success, r.message
        s = node.status()
        assert (s.n_measurements, s.n_rejected) == (2, 0), (s.n_measurements, s.n_rejected)
        # Points nobody samples: the working point at 40 is dropped when the destination point
        # at 50 arrives, and counted when the next working point replaces it.
        self.send(node, "working_point", self.cell["working"][1], "tracker", stamp=40.0)
        self.send(node, "destination_point", self.cell["destination"][1], "world", stamp=50.0)
        self.send(node, "working_point", self.cell["working"][2], "tracker", stamp=60.0)
        wait_for(lambda: node.status().n_rejected_malformed == 1, what="the unsampled point")
        assert node.status().n_measurements == 2

    def test_an_unsampled_dropped_point_counts_once_sample_max_age_passes(self):
        node = self.make_node(sample_max_age=0.2)
        self.send(node, "working_point", self.cell["working"][0], "tracker", stamp=1.0)
        self.send(node, "destination_point", self.cell["destination"][0], "world", stamp=5.0)
        wait_for(lambda: node.status().n_rejected_malformed == 1, what="the dropped point")
        r = self.take(node, "H1")
        assert not r.success and "the latest ~/working_point is stale" in r.message
        assert node.status().n_rejected == 1

    def test_pair_mode_counts_a_point_whose_stamp_is_not_a_time_once(self):
        """Pair mode: the topic callback counted the point, and ~/take_sample counted it
        again."""
        node = self.make_node(sample_max_age=60.0)
        self.send(node, "destination_point", self.cell["destination"][0], "world")
        pub = self.publisher(node, PointStamped, "working_point")
        msg = _point(self.cell["working"][0], "tracker")
        msg.header.stamp.nanosec = 2_000_000_000
        pub.publish(msg)
        wait_for(lambda: node.status().n_rejected_malformed == 1, what="the bad stamp counted")
        self.ros.client.destroy_publisher(pub)
        r = self.take(node, "H00")
        assert not r.success and "rejected (malformed)" in r.message
        assert node.status().n_rejected_malformed == 1

    @pytest.mark.skipif(not samples.TF2_ROS_MISSING, reason="tf2_ros is installed")
    def test_tf_source_is_refused_without_tf2_ros(self):
        node = self.make_node()
        result = node.set_parameters([Parameter("sample_destination_source", value="tf")])[0]
        assert not result.successful and "needs tf2_ros" in result.reason
        assert node.get_parameter("sample_destination_source").value == "topic"
        with pytest.raises(ValueError, match="needs tf2_ros"):
            RegistrationNode("reg_tf_refused", context=self.ros.context, parameter_overrides=[
                Parameter("state_dir", value=""),
                Parameter("sample_destination_source", value="tf")])

    @pytest.mark.skipif(bool(samples.TF2_ROS_MISSING),
                        reason=f"tf2_ros is not installed here: {samples.TF2_ROS_MISSING}")
    def test_tf_source_takes_the_destination_from_a_lookup(self):
        from geometry_msgs.msg import TransformStamped
        from tf2_msgs.msg import TFMessage

        from rbc_registration.ros.tf_static import STATIC_QOS

        node = self.make_node(point_mode="sample", sample_destination_source="tf",
                              sample_tf_child="tcp", sample_max_age=60.0)
        t = TransformStamped()
        t.header.frame_id, t.child_frame_id = "world", "tcp"
        t.transform.translation.x, t.transform.translation.y = 0.25, -0.5
        t.transform.translation.z, t.transform.rotation.w = 1.5, 1.0
        pub = self.ros.client.create_publisher(TFMessage, "/tf_static", STATIC_QOS)
        pub.publish(TFMessage(transforms=[t]))
        self.send(node, "working_point", self.cell["working"][0], "tracker")
        wait_for(lambda: self.take(node, "T0").success, what="a tf sample")
        self.ros.client.destroy_publisher(pub)
