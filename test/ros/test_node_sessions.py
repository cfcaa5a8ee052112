"""registration_node as a separate process with two sessions: a cell measured, the tracker moved,
part of it and every target measured again. Streamed once with the sessions declared in
``FiducialPair.session`` and once undeclared with a move well beyond the noise (the node opens
``auto-1`` itself): ``~/status`` and ``/diagnostics`` WARN naming the move and when, and
``~/correct_target`` answers (targets in the current session) equal the offline pipeline's on
the same data, before and after a restart from the journal. A session opened after the model
was built: targets wait for its model. ``~/take_sample`` takes a group.

DDS stays on loopback: test/conftest.py sets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a
per-process ROS_DOMAIN_ID, which the node process inherits.
"""

import json
import os

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("rbc_registration_interfaces.msg")

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from geometry_msgs.msg import Point, PointStamped  # noqa: E402
from rbc_registration_interfaces.msg import FiducialPair, RegistrationStatus  # noqa: E402
from rbc_registration_interfaces.srv import CorrectTarget, TakeSample  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from rbc_registration.core.constants import M_PER_MM  # noqa: E402
from rbc_registration.core.synthetic.cells import make_cell  # noqa: E402
from rbc_registration.core.synthetic.structure import moved_sessions  # noqa: E402
from rbc_registration.pipeline.inputs import PairMessage  # noqa: E402
from rbc_registration.pipeline.offline import evaluate_inputs, settings_for  # noqa: E402
from rbc_registration.ros.services import rebuild_requested_ns  # noqa: E402
from ros_helpers import (pair_msg, point_xyz, start_test_node, stop_process,  # noqa: E402
                         target_msg, wait_for)
from test_node import NodeTestBase  # noqa: E402

pytestmark = pytest.mark.ros
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
FRAMES = {"working_frame": "tracker", "destination_frame": "world"}
START_S = 100.0     # the stamp of the first measurement; one second apart


def _session_cell(move_sigmas: float):
    """Cell A (3D, single measurements) in two sessions, in metres."""
    sc = moved_sessions(make_cell("A", 5, repeats=1), 5, move_sigmas)
    return sc, sc.working * M_PER_MM, sc.destination * M_PER_MM


def _pair(fid: str, w, d, stamp_s: float, session: str) -> FiducialPair:
    msg = FiducialPair()
    msg.header.frame_id = FRAMES["working_frame"]
    msg.header.stamp.sec = int(stamp_s)
    msg.fiducial_id = fid
    msg.working_point = Point(x=float(w[0]), y=float(w[1]), z=float(w[2]))
    msg.destination_frame_id = FRAMES["destination_frame"]
    msg.destination_point = Point(x=float(d[0]), y=float(d[1]), z=float(d[2]))
    msg.session = session
    return msg


def _offline(sc, working, destination, labelled: bool):
    """The offline pipeline (the node's ingestion and builder) on the same measurements."""
    inputs = [PairMessage(k, START_S + k, fid, tuple(map(float, w)), FRAMES["working_frame"],
                          tuple(map(float, d)), FRAMES["destination_frame"],
                          session=s if labelled else "")
              for k, (fid, s, w, d) in enumerate(zip(sc.ids, sc.sessions, working,
                                                      destination))]
    return evaluate_inputs(inputs, settings_for(3, FRAMES))


def _stamp_ns(stamp) -> int:
    return stamp.sec * 10**9 + stamp.nanosec


@pytest.mark.parametrize("move_sigmas, labelled", [(3.0, True), (10.0, False)],
                         ids=["declared", "detected"])
def test_two_sessions_warn_and_answer_as_offline(tmp_path, ros_harness, move_sigmas, labelled):
    sc, working, destination = _session_cell(move_sigmas)
    began = sc.sessions.index("s2")
    n = len(sc.ids)
    name = f"reg_sessions_{os.getpid()}_{int(labelled)}"
    ros, client = ros_harness, ros_harness.client
    statuses, diagnostics = [], []
    client.create_subscription(RegistrationStatus, f"/{name}/status", statuses.append, LATCHED)
    client.create_subscription(DiagnosticArray, "/diagnostics", diagnostics.append, 100)
    state_dir = str(tmp_path / "state")
    with open(tmp_path / "node.log", "w") as log:
        node = start_test_node(name, state_dir=state_dir, log=log, **FRAMES)
        try:
            pub = client.create_publisher(FiducialPair, f"/{name}/fiducial_pairs", 1000)
            wait_for(lambda: pub.get_subscription_count() > 0, 30, "the node's subscription")
            for k, (fid, s, w, d) in enumerate(zip(sc.ids, sc.sessions, working, destination)):
                pub.publish(_pair(fid, w, d, START_S + k, s if labelled else ""))
            wait_for(lambda: statuses and statuses[-1].n_measurements == n, 60,
                     "every measurement accepted")
            response = ros.call(Trigger, f"/{name}/recompute", Trigger.Request(), 30)
            assert response.success, response.message
            requested = rebuild_requested_ns(response.message)
            wait_for(lambda: _stamp_ns(statuses[-1].last_recompute) >= requested, 120,
                     "the requested rebuild")
            status = statuses[-1]
            targets = sc.target_working[[k for k, s in enumerate(sc.target_sessions)
                                         if s == "s2"]] * M_PER_MM
            answers = [ros.call(CorrectTarget, f"/{name}/correct_target",
                                CorrectTarget.Request(target=target_msg(t)), 30)
                       for t in targets]
            mine = f"/{name}: registration"
            wait_for(lambda: any(s.name == mine and "re-stationed" in s.message
                                 for d in diagnostics for s in d.status), 30,
                     "the sessions' WARN on /diagnostics")
            diag = [s for d in diagnostics for s in d.status
                    if s.name == mine and "re-stationed" in s.message][-1]
        finally:
            assert stop_process(node) == 0, (tmp_path / "node.log").read_text()
    off = _offline(sc, working, destination, labelled)

    # a restart from the journal finds the same sessions (declared, or the bump again)
    statuses.clear()
    with open(tmp_path / "restart.log", "w") as log:
        node = start_test_node(name, state_dir=state_dir, log=log, **FRAMES)
        try:
            wait_for(lambda: statuses and statuses[-1].model_valid
                     and statuses[-1].n_measurements == n
                     and off.warning in statuses[-1].message, 120,
                     "the restarted node's model with the sessions' warning")
            again = [ros.call(CorrectTarget, f"/{name}/correct_target",
                              CorrectTarget.Request(target=target_msg(t)), 30)
                     for t in targets]
        finally:
            assert stop_process(node) == 0, (tmp_path / "restart.log").read_text()

    first, current = ("s1", "s2") if labelled else ("1", "auto-1")
    plan = off.fiducials.sessions
    assert plan.reference == current and plan.motion(first).moved
    # ~/status: the model's warning names the move, its size and when each session began
    assert status.model_valid and status.n_fiducials == len(off.fiducials.ids)
    assert off.warning and off.warning in status.message
    assert f"session '{first}' moved against '{current}'" in status.message
    assert f"'{current}' at {START_S + began:.3f} s" in status.message
    if not labelled:   # a bump detected live says so, at the measurement it began
        assert (f"the node detected a move of the working frame and opened session(s) "
                f"'auto-1' at stamp {START_S + began:.3f} s") in status.message
    # /diagnostics: WARN with the same line
    assert diag.level == DiagnosticStatus.WARN and off.warning in diag.message
    # ~/correct_target: targets in the current session, the offline model's answers
    tc = off.model.correct(targets)
    for k, a in enumerate(answers + again):
        k %= len(targets)
        assert a.success, a.message
        np.testing.assert_allclose(point_xyz(a.destination.point), tc.destination[k], atol=1e-9)
        np.testing.assert_allclose(point_xyz(a.corrected.point), tc.corrected[k], atol=1e-9)
        np.testing.assert_allclose(point_xyz(a.uncorrected.point), tc.uncorrected[k], atol=1e-9)


class TestTakeSampleGroup(NodeTestBase):
    """``~/take_sample`` takes ``group`` (in-process node, topic source): the sample and its
    journal record carry it, the model gets it, and another group for the fiducial is a
    conflict."""

    def send(self, node, topic, xyz, frame):
        pub = self.publisher(node, PointStamped, topic)
        before = node._samples._latest.get(topic.split("_")[0])
        msg = PointStamped()
        msg.header.frame_id = frame
        msg.point.x, msg.point.y, msg.point.z = (float(v) for v in xyz)
        pub.publish(msg)
        wait_for(lambda: node._samples._latest.get(topic.split("_")[0]) is not before,
                 what=f"{topic} received")
        self.ros.client.destroy_publisher(pub)

    def take(self, node, fiducial_id, group):
        return self.srv(node, TakeSample, "take_sample",
                        TakeSample.Request(fiducial_id=fiducial_id, group=group))

    def test_a_sample_carries_its_group(self, tmp_path):
        node = self.make_node(state_dir=str(tmp_path), point_mode="sample", sample_max_age=60.0)
        cell = self.cell
        self.send(node, "destination_point", cell["destination"][0], "world")
        self.send(node, "working_point", cell["working"][0], "tracker")
        r = self.take(node, "H00", "pose1")
        assert r.success, r.message
        assert r.pair.group == "pose1" and r.pair.session == ""
        record = json.loads((tmp_path / "journal.jsonl").read_text().splitlines()[-1])
        assert record["id"] == "H00" and record["g"] == "pose1" and "se" not in record
        self.send(node, "working_point", cell["working"][0] + 1e-5, "tracker")
        r = self.take(node, "H00", "pose2")
        assert not r.success and "rejected (conflict)" in r.message
        assert "fiducial 'H00' is in group 'pose1', this measurement says group 'pose2'" \
            in r.message
        assert node.status().n_rejected_conflict == 1 and node.status().n_measurements == 1
        assert node._ingest.fiducial_set().groups == ("pose1",)


class TestNewSession(NodeTestBase):
    """A session opened after the model was built (in-process node, rebuilds only on
    ~/recompute): ~/correct_target refuses until the model is of the new session, a new session
    that shares too few fiducials gives no model and says what to measure, and once it shares
    enough the answers are the offline pipeline's."""

    def correct(self, node, xyz):
        return self.srv(node, CorrectTarget, "correct_target",
                        CorrectTarget.Request(target=target_msg(xyz)))

    def test_targets_wait_for_the_model_of_the_new_session(self):
        node = self.make_node(debounce_period=30.0, **FRAMES)
        cell = self.cell
        self.stream(node)
        self.recompute(node)
        target = cell["targets"][0]
        assert self.correct(node, target).success
        shift = np.array([1e-3, -6e-4, 4e-4])       # the tracker moved by ~1.2 mm
        pub = self.publisher(node, FiducialPair, "fiducial_pairs")
        later = [0, 5, 17, 30, 47]                 # holes of the grid, spread

        def send(rows):
            before = node.status().n_measurements
            for k in rows:
                msg = pair_msg(cell, k, stamp_s=1000.0 + k)
                w = cell["working"][k] + shift
                msg.working_point = Point(x=float(w[0]), y=float(w[1]), z=float(w[2]))
                msg.session = "after lunch"
                pub.publish(msg)
            wait_for(lambda: node.status().n_measurements == before + len(rows),
                     what="the new session's measurements")

        send(later[:1])
        r = self.correct(node, target)
        assert not r.success and r.message == (
            "targets are in session 'after lunch', the model is still in session '1''s "
            "working frame: retry once ~/status shows the rebuild (n_pending 0)")
        self.recompute(node)
        r = self.correct(node, target)
        assert not r.success and "1 enabled fiducials, need min_fiducials=4 in session " \
            "'after lunch'" in r.message and "measure at least 4 fiducials" in r.message
        send(later[1:])
        state = self.recompute(node)
        assert state.fiducials.session == "after lunch"
        assert "session '1' moved against 'after lunch'" in state.warning
        r = self.correct(node, target + shift)
        assert r.success, r.message
        rows = list(range(len(cell["fid"])))
        off = evaluate_inputs(
            [PairMessage(k, 100.0 + k, str(cell["ids"][cell["fid"][k]]),
                         tuple(map(float, cell["working"][k])), FRAMES["working_frame"],
                         tuple(map(float, cell["destination"][k])), FRAMES["destination_frame"])
             for k in rows]
            + [PairMessage(0, 1000.0 + k, str(cell["ids"][cell["fid"][k]]),
                           tuple(map(float, cell["working"][k] + shift)),
                           FRAMES["working_frame"], tuple(map(float, cell["destination"][k])),
                           FRAMES["destination_frame"], session="after lunch")
               for k in later], settings_for(3, {**FRAMES, "debounce_period": 30.0}))
        tc = off.model.correct((target + shift)[None])
        np.testing.assert_allclose(point_xyz(r.destination.point), tc.destination[0],
                                   atol=1e-9)
        np.testing.assert_allclose(point_xyz(r.uncorrected.point), tc.uncorrected[0],
                                   atol=1e-9)
        self.ros.client.destroy_publisher(pub)
