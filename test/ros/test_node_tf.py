"""/tf_static follows the model: the node's own latched tf2_msgs/TFMessage publisher (the real
type, built from vendor/tf2_msgs) holds the newest registration for its child frame after every
rebuild, the one tf_broadcast chooses, and nothing of it after a reset. Each check subscribes
anew after the fact (a late joiner), from a node other than the publisher."""

import json

import numpy as np
import pytest

pytest.importorskip("rclpy")
TFMessage = pytest.importorskip("tf2_msgs.msg").TFMessage

from geometry_msgs.msg import TransformStamped  # noqa: E402
from rcl_interfaces.msg import Log  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import qos_profile_rosout_default  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from rbc_registration.ros.conversions import transform_to_matrix  # noqa: E402
from rbc_registration.ros.tf_static import STATIC_QOS, TOPIC  # noqa: E402
from ros_helpers import point_xyz, wait_for  # noqa: E402
from test_node import NodeTestBase  # noqa: E402

pytestmark = pytest.mark.ros


def _matrix(registration):
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = registration.rotation, registration.translation
    return m


class TestTfFollowsTheModel(NodeTestBase):

    def late_tf(self, node):
        """The latched /tf_static message of ``node``, as a subscriber created now gets it."""
        return self.latest(node, TFMessage, TOPIC, qos=STATIC_QOS)

    def entry(self, msg, child="tracker"):
        entries = [t for t in msg.transforms if t.child_frame_id == child]
        assert len(entries) <= 1, msg
        return entries[0] if entries else None

    def test_late_joiner_sees_the_newest_model_then_nothing_after_reset(self):
        node = self.make_node(tf_broadcast="corrected")
        models = []
        # Three rebuilds from growing sets of measurements: three different registrations.
        bounds = (0, 16, 30, self.n)
        for start, stop in zip(bounds, bounds[1:]):
            self.stream(node, range(start, stop))
            models.append(self.recompute(node).model)
        first, newest = _matrix(models[0].corrected), _matrix(models[-1].corrected)
        assert np.abs(first - newest).max() > 1e-7  # the models really moved

        msg = self.late_tf(node)
        entry = self.entry(msg)
        assert entry.header.frame_id == "world"
        np.testing.assert_allclose(transform_to_matrix(entry), newest, atol=1e-12)
        transform = self.latest(node, TransformStamped, f"/{node.get_name()}/transform")
        assert entry == transform  # /tf_static and ~/transform carry the same message
        infos = self.ros.client.get_publishers_info_by_topic(TOPIC)
        assert {i.topic_type for i in infos} == {"tf2_msgs/msg/TFMessage"}

        # tf_broadcast chooses which registration; 'none' takes the node's entry out.
        node.set_parameters([Parameter("tf_broadcast", value="uncorrected")])
        entry = self.entry(self.late_tf(node))
        np.testing.assert_allclose(transform_to_matrix(entry), _matrix(models[-1].uncorrected),
                                   atol=1e-12)
        node.set_parameters([Parameter("tf_broadcast", value="none")])
        assert self.entry(self.late_tf(node)) is None
        node.set_parameters([Parameter("tf_broadcast", value="corrected")])
        np.testing.assert_allclose(transform_to_matrix(self.entry(self.late_tf(node))), newest,
                                   atol=1e-12)

        assert self.srv(node, Trigger, "reset").success
        assert self.entry(self.late_tf(node)) is None  # a TFMessage without the child frame
        # A new model after the reset is published again.
        self.stream(node)
        model = self.recompute(node).model
        np.testing.assert_allclose(transform_to_matrix(self.entry(self.late_tf(node))),
                                   _matrix(model.corrected), atol=1e-12)

    def test_a_model_that_becomes_invalid_leaves_tf_static(self):
        """with fiducials disabled below min_fiducials the node refused to answer
        (model_valid false) while /tf_static kept the registration of the excluded fiducials."""
        from rbc_registration_interfaces.srv import SetFiducialEnabled
        node = self.make_node(tf_broadcast="corrected", min_fiducials=4)
        self.stream(node, range(5))
        model = self.recompute(node).model
        assert model is not None and self.entry(self.late_tf(node)) is not None
        for fid in model.ids[:2]:
            assert self.srv(node, SetFiducialEnabled, "set_fiducial_enabled",
                            SetFiducialEnabled.Request(fiducial_id=fid, enabled=False)).success
        assert self.recompute(node).model is None
        assert self.entry(self.late_tf(node)) is None
        node.set_parameters([Parameter("tf_broadcast", value="none")])
        node.set_parameters([Parameter("tf_broadcast", value="corrected")])
        assert self.entry(self.late_tf(node)) is None        # not brought back either
        assert self.srv(node, SetFiducialEnabled, "set_fiducial_enabled",
                        SetFiducialEnabled.Request(fiducial_id=model.ids[0], enabled=True)).success
        again = self.recompute(node).model
        np.testing.assert_allclose(transform_to_matrix(self.entry(self.late_tf(node))),
                                   _matrix(again.corrected), atol=1e-12)

    def test_a_status_naming_a_rebuild_comes_after_its_tf_static(self, monkeypatch):
        """Unguarded, the new model was served before its markers were built and its
        /tf_static published; the status timer could meanwhile publish a ~/status whose
        last_recompute named the rebuild, and a late joiner then got the registration of the
        model before. Here the markers take 0.5 s and the timer runs every 20 ms."""
        import time

        from rbc_registration.ros import publishing

        markers = publishing.markers_msg

        def slow_markers(*args, **kwargs):
            time.sleep(0.5)
            return markers(*args, **kwargs)

        node = self.make_node(tf_broadcast="corrected", status_period=0.02)
        self.stream(node, range(16))
        first = self.recompute(node).model
        monkeypatch.setattr(publishing, "markers_msg", slow_markers)
        self.stream(node, range(16, self.n))
        model = self.recompute(node).model
        assert len(model.ids) > len(first.ids)
        np.testing.assert_allclose(transform_to_matrix(self.entry(self.late_tf(node))),
                                   _matrix(model.corrected), atol=1e-12)

    def test_without_tf2_msgs_the_node_warns_and_keeps_working(self, monkeypatch):
        import rbc_registration.ros.tf_static as tf_static

        monkeypatch.setattr(tf_static, "MISSING", "tf2_msgs is not importable (test)")
        monkeypatch.setattr(tf_static.StaticTf.__init__, "__defaults__", (None,))
        logs = []
        sub = self.ros.client.create_subscription(Log, "/rosout", logs.append,
                                                  qos_profile_rosout_default)
        node = self.make_node()
        wait_for(lambda: any(m.name == node.get_name() and m.level == Log.WARN
                             and "static tf off: tf2_msgs is not importable" in m.msg
                             for m in logs), what="the WARN naming tf2_msgs")
        self.ros.client.destroy_subscription(sub)
        self.stream(node)
        model = self.recompute(node).model
        transform = self.latest(node, TransformStamped, f"/{node.get_name()}/transform")
        np.testing.assert_allclose(transform_to_matrix(transform), _matrix(model.corrected),
                                   atol=1e-12)
        assert self.ros.client.count_publishers(TOPIC) == 0


class TestResetDuringARebuild(NodeTestBase):

    def tf_entry(self, node):
        msg = self.latest(node, TFMessage, TOPIC, qos=STATIC_QOS)
        return next((t for t in msg.transforms if t.child_frame_id == "tracker"), None)

    def test_a_model_swapped_in_before_a_reset_is_neither_published_nor_saved(
            self, tmp_path, monkeypatch):
        """~/reset while a new model is being published (its markers take ~40 ms at 3,000
        fiducials): the forgotten model used to reach /tf_static and calibration.json after the
        reset (4 and 5 of 5 trials). Here the rebuild is held while its markers are
        built (before it is served and published) until the
        reset has answered."""
        import threading

        from rbc_registration.ros import publishing

        held, release = threading.Event(), threading.Event()
        hold = {"on": False}
        markers = publishing.markers_msg

        def slow_markers(*args, **kwargs):
            if hold["on"]:
                held.set()
                assert release.wait(30)
            return markers(*args, **kwargs)

        monkeypatch.setattr(publishing, "markers_msg", slow_markers)
        node = self.make_node(state_dir=str(tmp_path), tf_broadcast="corrected")
        self.stream(node, range(16))
        assert self.recompute(node).model is not None
        assert self.tf_entry(node) is not None
        hold["on"] = True
        self.stream(node, range(16, self.n))
        self.srv(node, Trigger, "recompute")
        assert held.wait(30)               # the new model built, its publication under way
        snapshot = tmp_path / "calibration.json"
        r = self.srv(node, Trigger, "reset")
        assert r.success, r.message
        assert not snapshot.exists()       # archived by the reset
        hold["on"] = False
        release.set()
        assert node._worker.wait(node._worker.request_now(), 30)   # the held one is done too
        assert node._snapshots.wait_idle(10)
        assert node.state.model is None and not node.status().model_valid
        assert self.tf_entry(node) is None
        if snapshot.exists():              # the rebuild after the reset: nothing of before
            saved = json.loads(snapshot.read_text())
            assert not saved["model_valid"] and saved["n_measurements"] == 0
            assert saved["fiducial_ids"] == []


class TestTargetFrames(NodeTestBase):
    """target_frames: each named target is a child frame of destination_frame on /tf_static at
    its ~/correct_target destination, replaced with every model, changed with the parameter,
    removed on reset, and published from a loaded calibration's answers before a live model."""

    def late_tf(self, node):
        return self.latest(node, TFMessage, TOPIC, qos=STATIC_QOS)

    def frames(self, msg):
        return {t.child_frame_id: t for t in msg.transforms}

    def entries(self, names):
        return [f"{name}:{x!r},{y!r},{z!r}"
                for name, (x, y, z) in zip(names, self.cell["targets"].tolist())]

    def assert_at_destinations(self, node, msg, names, atol=1e-12):
        frames = self.frames(msg)
        for name, target in zip(names, self.cell["targets"]):
            r = self.correct(node, target)
            assert r.success, r.message
            t = frames[name]
            assert t.header.frame_id == "world"
            m = transform_to_matrix(t)
            np.testing.assert_allclose(m[:3, :3], np.eye(3), atol=0)
            np.testing.assert_allclose(m[:3, 3], point_xyz(r.destination.point), rtol=0,
                                       atol=atol)
        return frames

    def test_targets_follow_each_model_the_parameter_and_a_reset(self):
        names = ["peg_a", "peg_b"]
        node = self.make_node(target_frames=self.entries(names))
        self.stream(node, range(30))
        first = self.recompute(node).model
        msg = self.late_tf(node)
        assert set(self.frames(msg)) == {"tracker", *names}
        before = self.assert_at_destinations(node, msg, names)
        assert first.decision.apply   # the destination carries the correction

        self.stream(node, range(30, self.n))
        self.recompute(node)
        msg = self.late_tf(node)
        after = self.assert_at_destinations(node, msg, names)
        moved = [np.abs(transform_to_matrix(after[n]) - transform_to_matrix(before[n])).max()
                 for n in names]
        assert min(moved) > 1e-9   # replaced with the new model

        result = node.set_parameters([Parameter("target_frames", Parameter.Type.STRING_ARRAY,
                                                self.entries(["peg_c"]))])
        assert result[0].successful, result[0].reason
        msg = self.late_tf(node)
        assert set(self.frames(msg)) == {"tracker", "peg_c"}
        self.assert_at_destinations(node, msg, ["peg_c"])
        bad = node.set_parameters([Parameter("target_frames", Parameter.Type.STRING_ARRAY,
                                             ["peg_d:1,2"])])
        assert not bad[0].successful and "must be NAME:X,Y,Z" in bad[0].reason
        assert set(self.frames(self.late_tf(node))) == {"tracker", "peg_c"}   # kept
        cleared = node.set_parameters([Parameter("target_frames", Parameter.Type.STRING_ARRAY,
                                                 [])])
        assert cleared[0].successful, cleared[0].reason
        assert set(self.frames(self.late_tf(node))) == {"tracker"}
        node.set_parameters([Parameter("target_frames", Parameter.Type.STRING_ARRAY,
                                       self.entries(["peg_c"]))])

        assert self.srv(node, Trigger, "reset").success
        wait_for(lambda: not self.frames(self.late_tf(node)), what="an empty /tf_static")

    def test_a_loaded_calibration_publishes_the_targets_before_a_live_model(self, tmp_path):
        names = ["peg_a", "peg_b", "peg_c"]
        first = self.make_node(state_dir=str(tmp_path / "a"))
        self.stream(first)
        self.recompute(first)
        assert self.srv(first, Trigger, "save").success
        live = [point_xyz(self.correct(first, t).destination.point)
                for t in self.cell["targets"][:3]]
        self.ros.remove(first)
        self.nodes.remove(first)

        second = self.make_node(state_dir="", target_frames=self.entries(names),
                                calibration_file=str(tmp_path / "a" / "calibration.yaml"))
        assert second.status().n_measurements == 0
        frames = self.frames(self.late_tf(second))
        assert set(frames) == {"tracker", *names}
        for name, xyz in zip(names, live):
            np.testing.assert_allclose(transform_to_matrix(frames[name])[:3, 3], xyz, rtol=0,
                                       atol=1e-9)

    def test_a_target_frame_named_as_a_node_frame_is_refused(self):
        with pytest.raises(ValueError, match="target_frames\\[0\\]: the name 'world' is "
                                             "destination_frame"):
            self.make_node(target_frames=["world:0,0,0"])
