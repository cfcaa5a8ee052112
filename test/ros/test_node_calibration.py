"""Saved calibrations through a node restart: the first node registers and saves
(``state_dir/calibration.yaml``); a second node with an EMPTY state_dir and only
``calibration_file`` publishes the same transform on ~/transform and /tf_static before any
measurement, says so in ~/status, answers ~/correct_target(s) from the file's answers as the
first node did, and a live model replaces it once measurements arrive."""

import importlib.util
import os
import shutil

import numpy as np
import pytest
import yaml

pytest.importorskip("rclpy")
TFMessage = pytest.importorskip("tf2_msgs.msg").TFMessage

from rbc_registration.pipeline.files import LOCK_NAME  # noqa: E402
from geometry_msgs.msg import TransformStamped  # noqa: E402
from rbc_registration_interfaces.msg import RegistrationStatus  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from rbc_registration.io.calibration import read_calibration  # noqa: E402
from rbc_registration.ros.conversions import transform_to_matrix  # noqa: E402
from rbc_registration.ros.node import RegistrationNode  # noqa: E402
from rbc_registration.ros.tf_static import STATIC_QOS, TOPIC  # noqa: E402
from rbc_registration_interfaces.srv import CorrectTargets  # noqa: E402
from rcl_interfaces.msg import Log  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import qos_profile_rosout_default  # noqa: E402
from ros_helpers import point_xyz, target_msg, wait_for  # noqa: E402
from test_node import NodeTestBase  # noqa: E402

pytestmark = pytest.mark.ros


class TestSavedCalibration(NodeTestBase):

    def transform(self, node):
        return self.latest(node, TransformStamped, f"/{node.get_name()}/transform")

    def tf_entry(self, node):
        msg = self.latest(node, TFMessage, TOPIC, qos=STATIC_QOS)
        return [t for t in msg.transforms if t.child_frame_id == "tracker"]

    def test_round_trip_through_a_restart_with_an_empty_state_dir(self, tmp_path):
        first_dir, second_dir = tmp_path / "first", tmp_path / "second"
        first = self.make_node(state_dir=str(first_dir), decision="on")
        self.stream(first)
        model = self.recompute(first).model
        saved = self.srv(first, Trigger, "save")
        path = first_dir / "calibration.yaml"
        assert saved.success, saved.message
        assert str(path) in saved.message and "calibration.json" in saved.message
        assert "ros2 run tf2_ros static_transform_publisher --x " in saved.message
        cal = read_calibration(str(path))
        assert (cal.parent_frame, cal.child_frame, cal.registration) == ("world", "tracker",
                                                                         "corrected")
        assert cal.decision.apply and cal.n_fiducials == len(model.ids)
        before = transform_to_matrix(self.transform(first))
        live_answers = self.srv(first, CorrectTargets, "correct_targets", CorrectTargets.Request(
            targets=[target_msg(t) for t in self.cell["targets"]]))
        assert live_answers.success, live_answers.message
        self.ros.remove(first)  # the restart: the first node is gone
        self.nodes.remove(first)

        second_dir.mkdir()
        second = self.make_node(state_dir=str(second_dir), calibration_file=str(path))
        assert second.status().n_measurements == 0
        np.testing.assert_allclose(transform_to_matrix(self.transform(second)), before,
                                   atol=1e-12)
        (entry,) = self.tf_entry(second)
        np.testing.assert_allclose(transform_to_matrix(entry), before, atol=1e-12)
        status = self.latest(second, RegistrationStatus, f"/{second.get_name()}/status")
        assert f"calibration from {path}" in status.message and not status.model_valid
        # the file's answers: the live node's, to 1e-9 m, saying they come from the file
        from_file = self.srv(second, CorrectTargets, "correct_targets", CorrectTargets.Request(
            targets=[target_msg(t) for t in self.cell["targets"]]))
        assert from_file.success, from_file.message
        assert f"from {path}" in from_file.message
        method = model.decision.method
        assert method != "uncorrected"
        for live_r, file_r in zip(live_answers.results, from_file.results, strict=True):
            assert live_r.method == method and file_r.method == f"{method} (calibration file)"
            assert file_r.correction_applied == live_r.correction_applied
            assert file_r.inside_hull == live_r.inside_hull
            for field in ("destination", "corrected", "uncorrected"):
                np.testing.assert_allclose(point_xyz(getattr(file_r, field).point),
                                           point_xyz(getattr(live_r, field).point), rtol=0,
                                           atol=1e-9)
            assert file_r.expected_tre == pytest.approx(live_r.expected_tre, rel=1e-9)
            assert file_r.tre_bound == pytest.approx(live_r.tre_bound, rel=1e-9)
        single = self.correct(second, self.cell["targets"][0])
        assert single.success and single.method == f"{method} (calibration file)"
        np.testing.assert_allclose(point_xyz(single.destination.point),
                                   point_xyz(live_answers.results[0].destination.point),
                                   rtol=0, atol=1e-9)
        # nothing written but the (empty) journal and the state_dir lock
        assert [n for n in os.listdir(second_dir) if n not in ("journal.jsonl", LOCK_NAME)] == []

        # Measurements arrive: the live model (here of half the fiducials) replaces the file.
        half = [k for k in range(self.n) if self.cell["fid"][k] % 2 == 0]
        self.stream(second, half)
        live = self.recompute(second).model
        assert np.abs(live.corrected.translation - model.corrected.translation).max() > 1e-7
        live_m = np.eye(4)
        live_m[:3, :3], live_m[:3, 3] = live.corrected.rotation, live.corrected.translation
        np.testing.assert_allclose(transform_to_matrix(self.transform(second)), live_m,
                                   atol=1e-12)
        np.testing.assert_allclose(transform_to_matrix(self.tf_entry(second)[0]), live_m,
                                   atol=1e-12)
        assert "calibration from" not in second.status().message

    def test_an_uncorrected_calibration_is_published_as_the_uncorrected_registration(self,
                                                                                  tmp_path):
        """A file of ``registration: uncorrected`` goes on ~/transform_uncorrected (not on
        ~/transform, the topic of the corrected registration {R_c, tau_c}) and /tf_static, where
        the live model's {R_u, tau_u} later replaces it."""
        first = self.make_node(state_dir=str(tmp_path / "a"), tf_broadcast="uncorrected")
        self.stream(first)
        self.recompute(first)
        assert self.srv(first, Trigger, "save").success
        path = tmp_path / "a" / "calibration.yaml"
        cal = read_calibration(str(path))
        assert cal.registration == "uncorrected"
        second = self.make_node(state_dir="", calibration_file=str(path))
        got = self.latest(second, TransformStamped, f"/{second.get_name()}/transform_uncorrected")
        np.testing.assert_allclose(transform_to_matrix(got), cal.transform_matrix(), atol=1e-12)
        (entry,) = self.tf_entry(second)
        np.testing.assert_allclose(transform_to_matrix(entry), cal.transform_matrix(),
                                   atol=1e-12)

    def test_a_calibration_of_other_frames_or_a_bad_file_is_refused(self, tmp_path):
        node = self.make_node(state_dir=str(tmp_path / "a"))
        self.stream(node)
        self.recompute(node)
        assert self.srv(node, Trigger, "save").success
        path = str(tmp_path / "a" / "calibration.yaml")
        for params, match in (({"working_frame": "laser"}, "child_frame is 'tracker', but the "
                                                          "node has 'laser'"),
                              ({"dimension": 2}, "dimension is 3, but the node has 2")):
            with pytest.raises(ValueError, match=match):
                RegistrationNode("reg_badcal", context=self.ros.context, parameter_overrides=[
                    Parameter("state_dir", value=""), Parameter("calibration_file", value=path),
                    *(Parameter(k, value=v) for k, v in params.items())])
        (tmp_path / "bad.yaml").write_text("format: rbc_registration_calibration\n")
        with pytest.raises(ValueError, match="bad.yaml: .*missing"):
            RegistrationNode("reg_badcal2", context=self.ros.context, parameter_overrides=[
                Parameter("state_dir", value=""),
                Parameter("calibration_file", value=str(tmp_path / "bad.yaml"))])

    def test_a_file_without_answers_publishes_tf_and_says_it_answers_no_targets(self, tmp_path):
        """A format version 2 file (no ``answers``, as files written by an older package) is
        published, and ~/correct_target says the file answers no targets."""
        first = self.make_node(state_dir=str(tmp_path / "a"))
        self.stream(first)
        self.recompute(first)
        assert self.srv(first, Trigger, "save").success
        doc = yaml.safe_load((tmp_path / "a" / "calibration.yaml").read_text())
        del doc["answers"]
        doc["format_version"] = 2
        path = tmp_path / "v2.yaml"
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
        second = self.make_node(state_dir="", calibration_file=str(path))
        (entry,) = self.tf_entry(second)
        np.testing.assert_allclose(transform_to_matrix(entry),
                                   read_calibration(str(path)).transform_matrix(), atol=1e-12)
        r = self.correct(second, self.cell["targets"][0])
        assert not r.success
        assert f"{path} holds no answers" in r.message and "answers no targets" in r.message

    def test_save_without_a_model_says_why(self, tmp_path):
        node = self.make_node(state_dir=str(tmp_path))
        r = self.srv(node, Trigger, "save")
        assert not r.success and "no model to save as a calibration yet" in r.message
        assert not (tmp_path / "calibration.yaml").exists()


class TestRestartWarnings(NodeTestBase):
    """A restart on an old state_dir warns only about parameters that change the model built
    from the journal (``Spec.changes_model``): not about ``calibration_file`` or ``point_mode``,
    once about another ``sigma``."""

    def start_logs(self, **params):
        """Start a node and return its WARN lines up to its start-up line, then stop it."""
        logs = []
        sub = self.ros.client.create_subscription(Log, "/rosout", logs.append,
                                                  qos_profile_rosout_default)
        node = self.make_node(**params)
        name = node.get_name()
        wait_for(lambda: any(m.name == name and m.msg.startswith("registering ")
                             for m in logs), what="the start-up line")
        self.ros.client.destroy_subscription(sub)
        self.ros.remove(node)
        self.nodes.remove(node)
        return [m.msg for m in logs if m.name == name and m.level == Log.WARN]

    def test_only_parameters_that_change_the_model_are_named(self, tmp_path):
        state_dir = tmp_path / "cell"
        first = self.make_node(state_dir=str(state_dir))
        self.stream(first)
        self.recompute(first)
        assert self.srv(first, Trigger, "save").success
        wait_for(lambda: (state_dir / "calibration.json").exists(), what="the snapshot")
        self.ros.remove(first)
        self.nodes.remove(first)

        warnings = self.start_logs(state_dir=str(state_dir), point_mode="sample",
                                   calibration_file=str(state_dir / "calibration.yaml"))
        assert not [w for w in warnings if "built with other parameters" in w], warnings

        warnings = [w for w in self.start_logs(state_dir=str(state_dir), sigma=1e-4)
                    if "built with other parameters" in w]
        assert len(warnings) == 1, warnings
        assert "sigma 0.0 (now 0.0001)" in warnings[0]
        assert "point_mode" not in warnings[0] and "calibration_file" not in warnings[0]


def _launch_module(name):
    path = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(
        os.path.abspath(__file__)))), "launch", name)
    spec = importlib.util.spec_from_file_location(name.replace(".", "_"), path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class TestNamedCalibrations(NodeTestBase):
    """calibration_name: ~/save writes state_dir/calibrations/NAME.yaml; calibration_file:=NAME
    loads it, also as publish.launch.py calibration:=NAME passes it on."""

    def test_save_under_a_name_and_load_it_by_name(self, tmp_path):
        state_dir = tmp_path / "cell"
        first = self.make_node(state_dir=str(state_dir))
        self.stream(first)
        self.recompute(first)
        result = first.set_parameters([Parameter("calibration_name", value="line_1")])
        assert result[0].successful, result[0].reason
        saved = self.srv(first, Trigger, "save")
        path = state_dir / "calibrations" / "line_1.yaml"
        assert saved.success and str(path) in saved.message, saved.message
        assert not (state_dir / "calibration.yaml").exists()
        bad = first.set_parameters([Parameter("calibration_name", value="../up")])
        assert not bad[0].successful and "a calibration name is 1-100 letters" in bad[0].reason
        live = self.correct(first, self.cell["targets"][0])
        self.ros.remove(first)
        self.nodes.remove(first)

        # publish.launch.py calibration:=line_1 -> registration.launch.py -> the node's
        # parameters (state_dir:=auto derived from ROS_HOME), with the named file in place
        values = {n: d for n, d, _ in _launch_module("registration.launch.py").ARGUMENTS}
        values.update(_launch_module("publish.launch.py").included_arguments(
            {"calibration": "line_1"}))
        values["params_file"] = ""
        ros_home = tmp_path / "ros_home"
        _, overrides = _launch_module("registration.launch.py").node_parameters(
            values, environ={"ROS_HOME": str(ros_home)})
        assert overrides["calibration_file"] == "line_1"
        launched_dir = overrides["state_dir"]
        assert launched_dir.startswith(str(ros_home))
        os.makedirs(os.path.join(launched_dir, "calibrations"))
        shutil.copy(path, os.path.join(launched_dir, "calibrations", "line_1.yaml"))

        second = self.make_node(**overrides)
        (entry,) = [t for t in self.latest(second, TFMessage, TOPIC, qos=STATIC_QOS).transforms
                    if t.child_frame_id == "tracker"]
        np.testing.assert_allclose(transform_to_matrix(entry),
                                   read_calibration(str(path)).transform_matrix(), atol=1e-12)
        r = self.correct(second, self.cell["targets"][0])
        assert r.success and r.method.endswith(" (calibration file)"), r.message
        assert os.path.join(launched_dir, "calibrations", "line_1.yaml") in r.message
        np.testing.assert_allclose(point_xyz(r.destination.point),
                                   point_xyz(live.destination.point), rtol=0, atol=1e-9)

    def test_a_name_that_is_not_there_or_not_a_name_is_refused(self, tmp_path):
        with pytest.raises(ValueError, match=r"calibrations/absent\.yaml"):
            RegistrationNode("reg_noname", context=self.ros.context, parameter_overrides=[
                Parameter("state_dir", value=str(tmp_path)),
                Parameter("calibration_file", value="absent")])
        with pytest.raises(ValueError, match="is a calibration name .* but state_dir is empty"):
            RegistrationNode("reg_noname2", context=self.ros.context, parameter_overrides=[
                Parameter("state_dir", value=""), Parameter("calibration_file", value="absent")])
