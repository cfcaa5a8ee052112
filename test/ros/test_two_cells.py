"""Two cells on one graph: two registration_node processes with the same node name in different
namespaces (``--ros-args -r __ns:=/cell_a``), each with its default state_dir
($ROS_HOME/rbc_registration/<namespace>.<name>, a directory of its own), register two cells
independently (different transforms), and both latch their own /tf_static entry."""

import json
import os

import numpy as np
import pytest

pytest.importorskip("rclpy")
TFMessage = pytest.importorskip("tf2_msgs.msg").TFMessage

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import TransformStamped  # noqa: E402
from rbc_registration_interfaces.msg import FiducialPair, RegistrationStatus  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from rbc_registration.ros.conversions import transform_to_matrix  # noqa: E402
from rbc_registration.ros.process import start_node, stop_process  # noqa: E402
from rbc_registration.ros.tf_static import TOPIC  # noqa: E402
from ros_helpers import expected_state, make_cell, pair_msg, wait_for  # noqa: E402

pytestmark = pytest.mark.ros
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
# A /tf_static reader as tf2_ros's StaticListenerQoS: depth 100, so the latched messages of
# several publishers arriving together are all kept (depth 1 would keep only the last).
TF_LISTENER = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
NAME = "registration_node"  # the same name in both namespaces


def _moved(cell, angle, shift):
    """``cell`` with its destination frame moved rigidly: another cell, another registration."""
    c, s = np.cos(angle), np.sin(angle)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return {**cell, "destination": cell["destination"] @ rot.T + shift}


def _latest(client, msg_type, topic, predicate, qos=LATCHED):
    """The newest message on ``topic`` that satisfies ``predicate`` (a new subscription)."""
    msgs = []
    sub = client.create_subscription(msg_type, topic, msgs.append, qos)
    try:
        wait_for(lambda: any(map(predicate, msgs)), timeout=60, what=topic)
        return [m for m in msgs if predicate(m)][-1]
    finally:
        client.destroy_subscription(sub)


def _publish_cell(client, topic, cell, frame):
    pub = client.create_publisher(FiducialPair, topic, 1000)
    wait_for(lambda: pub.get_subscription_count() > 0, timeout=30, what=f"a node on {topic}")
    for k in range(len(cell["fid"])):
        pub.publish(pair_msg(cell, k, stamp_s=100.0 + k, frame=frame))


def _matrix(registration):
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = registration.rotation, registration.translation
    return m


def test_two_namespaced_nodes_register_two_cells_each_in_its_own_state_dir(tmp_path,
                                                                           ros_harness):
    ros_home = tmp_path / "ros_home"
    cells = {"cell_a": (make_cell(seed=1), "tracker_a"),
             "cell_b": (_moved(make_cell(seed=2), 0.7, [2.0, -1.0, 0.3]), "tracker_b")}
    procs, logs = {}, {}
    try:
        for ns, (_, frame) in cells.items():
            logs[ns] = open(tmp_path / f"{ns}.log", "w")
            procs[ns] = start_node(NAME, {"debounce_period": 0.05, "working_frame": frame},
                                   log=logs[ns], env={"ROS_HOME": str(ros_home)},
                                   ros_args=["-r", f"__ns:=/{ns}"])
        client = ros_harness.client
        for ns, (cell, frame) in cells.items():
            _publish_cell(client, f"/{ns}/{NAME}/fiducial_pairs", cell, frame)
        for ns, (cell, _) in cells.items():
            n = len(cell["fid"])
            _latest(client, RegistrationStatus, f"/{ns}/{NAME}/status",
                    lambda m, n=n: m.n_measurements == n)  # every measurement accepted
            r = ros_harness.call(Trigger, f"/{ns}/{NAME}/recompute", Trigger.Request(),
                                 timeout=30)
            assert r.success, r.message

        got = {}
        for ns, (cell, frame) in cells.items():
            expected = expected_state(cell, working_frame=frame).model
            got[ns] = transform_to_matrix(_latest(client, TransformStamped,
                                                  f"/{ns}/{NAME}/transform", lambda m: True))
            np.testing.assert_allclose(got[ns], _matrix(expected.corrected), atol=1e-9)
            # Its own state_dir, derived from namespace and name; the journal holds its cell.
            state_dir = ros_home / "rbc_registration" / f"{ns}.{NAME}"
            lines = (state_dir / "journal.jsonl").read_text().splitlines()
            assert len(lines) == 1 + len(cell["fid"])  # header + every measurement
            assert json.loads(lines[0])["working_frame"] == frame
        assert np.abs(got["cell_a"] - got["cell_b"]).max() > 0.1  # two different registrations
        assert sorted(os.listdir(ros_home / "rbc_registration")) == [f"cell_a.{NAME}",
                                                                     f"cell_b.{NAME}"]

        # /diagnostics: one status per node, named by its fully qualified name.
        names = set()
        sub = client.create_subscription(DiagnosticArray, "/diagnostics", lambda m: names.update(
            s.name for s in m.status), 10)
        want = {f"/{ns}/{NAME}: registration" for ns in cells}
        wait_for(lambda: want <= names, timeout=30, what=f"{want} on /diagnostics")
        client.destroy_subscription(sub)
        assert f"{NAME}: registration" not in names

        # A late joiner of /tf_static (another process) gets both nodes' latched entries.
        entries = {}
        sub = client.create_subscription(
            TFMessage, TOPIC, lambda m: entries.update({t.child_frame_id: t for t in
                                                        m.transforms}), TF_LISTENER)
        wait_for(lambda: {"tracker_a", "tracker_b"} <= set(entries), timeout=30,
                 what="both cells on /tf_static")
        client.destroy_subscription(sub)
        for ns, (_, frame) in cells.items():
            np.testing.assert_allclose(transform_to_matrix(entries[frame]), got[ns], atol=1e-12)
    finally:
        for ns, proc in procs.items():
            assert stop_process(proc) == 0, (tmp_path / f"{ns}.log").read_text()
            logs[ns].close()
