"""registration_node as a separate process: a separate client process streams pairs and corrects
targets; SIGKILL mid-stream and restart loses no accepted measurement and gives the same model.

DDS stays on loopback: test/conftest.py sets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a
per-process ROS_DOMAIN_ID, which the subprocesses inherit.
"""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("rbc_registration_interfaces.msg")

from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from rbc_registration_interfaces.msg import FiducialPair, RegistrationStatus  # noqa: E402
from rbc_registration.ros.services import rebuild_requested_ns  # noqa: E402
from rbc_registration_interfaces.srv import CorrectTarget  # noqa: E402

from ros_helpers import (RosTestBase, answer_key, expected_state, make_cell,  # noqa: E402
                         pair_msg, start_test_node, stop_process, target_msg, wait_for)

pytestmark = pytest.mark.ros
HERE = os.path.dirname(os.path.abspath(__file__))
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def expected_answers(cell, indices=None):
    model = expected_state(cell, indices, debounce_period=0.05).model
    tc = model.correct(cell["targets"])
    return tc


def status_sub(ros, name):
    """Collect ``/<name>/status`` messages (latched) in a list; returns (list, subscription)."""
    statuses = []
    sub = ros.client.create_subscription(RegistrationStatus, f"/{name}/status", statuses.append,
                                         LATCHED)
    return statuses, sub


def recompute_and_wait(ros, name, timeout=60.0):
    """``~/recompute`` (answered at once), then wait until ``~/status`` shows the rebuild."""
    response = ros.call(Trigger, f"/{name}/recompute", Trigger.Request(), 30)
    assert response.success, response.message
    requested = rebuild_requested_ns(response.message)
    statuses, sub = status_sub(ros, name)
    try:
        wait_for(lambda: statuses and stamp_ns(statuses[-1].last_recompute) >= requested,
                 timeout, what="the requested rebuild in ~/status")
    finally:
        ros.client.destroy_subscription(sub)


def stamp_ns(stamp):
    return stamp.sec * 10**9 + stamp.nanosec


def process_answers(ros, name, cell):
    """Recompute, then the answer keys of ``~/correct_target`` for every target of ``cell``."""
    recompute_and_wait(ros, name)
    return [answer_key(ros.call(CorrectTarget, f"/{name}/correct_target",
                                CorrectTarget.Request(target=target_msg(t)), 30))
            for t in cell["targets"]]


def check_answers(answers, tc):
    assert len(answers) == len(tc.corrected)
    for k, a in enumerate(answers):
        success, destination, corrected, uncorrected, correction = a[:5]
        assert success
        np.testing.assert_allclose(corrected, tc.corrected[k], atol=1e-12)
        np.testing.assert_allclose(uncorrected, tc.uncorrected[k], atol=1e-12)
        np.testing.assert_allclose(correction, tc.correction[k], atol=1e-12)


def test_separate_client_process_streams_pairs_and_corrects_targets(tmp_path):
    cell = make_cell(seed=3)
    np.savez(tmp_path / "cell.npz", **cell)
    name = f"reg_proc_{os.getpid()}"
    with open(tmp_path / "node.log", "w") as log:
        node = start_test_node(name, log=log)
        try:
            client = subprocess.run(
                [sys.executable, os.path.join(HERE, "stream_client.py"), name,
                 str(tmp_path / "cell.npz"), str(tmp_path / "answers.json")],
                env=dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST"),
                capture_output=True, text=True, timeout=120)
            assert client.returncode == 0, client.stdout + client.stderr
        finally:
            stop_process(node)
    answers = json.loads((tmp_path / "answers.json").read_text())
    check_answers(answers, expected_answers(cell))
    assert node.returncode == 0, (tmp_path / "node.log").read_text()


@pytest.mark.parametrize("params, reason", [
    ({"dimension": 4}, "cannot start"),
    # tf2 drops a transform of a frame into itself: the node would latch a /tf_static no one gets
    ({"working_frame": "world", "destination_frame": "world"},
     "cannot start: working_frame must differ from destination_frame, both are 'world'"),
    # -p decision:=off: YAML makes it a boolean; the reason says to quote it
    ({"decision": "off"}, "cannot start: Wrong parameter type: decision must be of type string, "
                          "got bool False (YAML reads an unquoted on, off"),
])
def test_a_bad_parameter_stops_the_node_with_a_reason(tmp_path, params, reason):
    with open(tmp_path / "node.log", "w") as log:
        proc = start_test_node(f"reg_bad_{os.getpid()}", log=log, **params)
        assert proc.wait(timeout=60) == 1
    assert reason in (tmp_path / "node.log").read_text()


@pytest.mark.parametrize("moment", ["make", "spin"])
def test_a_sigterm_while_the_node_is_made_or_waits_is_a_clean_stop(tmp_path, moment):
    """SIGTERM (ros2 launch stopping a node) while the node is being created (``make``), or
    between the executor's context check and its next wait (``spin``): before, the creation
    failed on the shut-down context with a traceback or ``cannot start: RCLError``, exit 1, and
    the wait with an ``RCLError`` traceback, exit 1 (seen once in CI); now exit 0,
    one INFO line while starting and none while spinning, and the state_dir is released."""
    state_dir = tmp_path / "state"
    with open(tmp_path / "node.log", "w") as log:
        proc = start_test_node(f"reg_term_{os.getpid()}", state_dir, log,
                               command=(sys.executable,
                                        os.path.join(HERE, "sigterm_at_moment.py")),
                               env={"RBC_SIGTERM_AT": moment})
        assert proc.wait(timeout=60) == 0, (tmp_path / "node.log").read_text()
    text = (tmp_path / "node.log").read_text()
    assert ("stopped while starting (shutdown requested)" in text) == (moment == "make"), text
    if moment == "spin":
        assert "registering" in text, text          # the node was made and spun
    assert "Traceback" not in text and "cannot start" not in text and "FATAL" not in text
    with open(tmp_path / "node2.log", "w") as log:       # the lock was released
        proc = start_test_node(f"reg_term2_{os.getpid()}", state_dir, log)
        try:
            wait_for(lambda: "registering" in (tmp_path / "node2.log").read_text(), 60,
                     "the second node's start")
        finally:
            assert stop_process(proc) == 0, (tmp_path / "node2.log").read_text()


@pytest.mark.parametrize("delay", [0.6, 1.0, 1.4, 1.8])
def test_a_sigterm_at_any_moment_of_the_start_is_never_a_traceback(tmp_path, delay):
    """A real SIGTERM from outside at moments spread over the start (imports, rclpy.init, the
    node's creation, the first spin): the process ends at once, by the signal itself (-15,
    before rclpy's handler exists) or with status 0, never with a traceback or a FATAL line."""
    with open(tmp_path / "node.log", "w") as log:
        proc = start_test_node(f"reg_term_{os.getpid()}", tmp_path / "state", log)
        time.sleep(delay)
        rc = stop_process(proc, signal.SIGTERM)
    text = (tmp_path / "node.log").read_text()
    assert rc in (0, -signal.SIGTERM), text
    assert "Traceback" not in text and "FATAL" not in text, text


class TestKillAndRestart(RosTestBase):
    """The test process is the client; the node is a subprocess killed with SIGKILL."""

    def status_sub(self, name):
        return status_sub(self.ros, name)

    def answers(self, name, cell):
        return process_answers(self.ros, name, cell)

    def test_kill_9_mid_stream_then_restart_gives_the_same_model(self, tmp_path):
        cell = make_cell(seed=5, repeats=4)
        n = len(cell["fid"])
        state_dir = tmp_path / "state"
        name = f"reg_kill_{os.getpid()}"
        log = open(tmp_path / "node.log", "w")
        node = start_test_node(name, state_dir, log, status_period=0.02)
        statuses, sub = self.status_sub(name)
        pub = self.ros.client.create_publisher(FiducialPair, f"/{name}/fiducial_pairs", 1000)
        try:
            wait_for(lambda: pub.get_subscription_count() > 0, 30, "the node's subscription")
            # Stream at ~500 Hz and SIGKILL the node in the middle of the stream, while it is
            # receiving and journaling: once it has acknowledged some (under load its first
            # status can come after the first quarter), right after the second quarter.
            published = 0
            while published < n // 2:
                if published == n // 4:
                    wait_for(lambda: any(s.n_measurements for s in statuses), 30,
                             "a first acknowledgement")
                pub.publish(pair_msg(cell, published, stamp_s=100.0 + published))
                published += 1
                time.sleep(0.002)
            node.send_signal(signal.SIGKILL)
            node.wait(timeout=15)
            acknowledged = max((s.n_measurements for s in statuses), default=0)
            assert 0 < acknowledged <= published

            # Restart: every measurement the node had acknowledged is back.
            statuses.clear()
            node = start_test_node(name, state_dir, log)
            wait_for(lambda: statuses and statuses[-1].model_valid, 30, "restored model")
            restored = statuses[-1].n_measurements
            print(f"published {published}, acknowledged {acknowledged}, restored {restored}")
            assert acknowledged <= restored <= published
            restored_answers = self.answers(name, cell)
            check_answers(restored_answers, expected_answers(cell, range(restored)))

            # Stream the rest; the node ends with the model of all pairs.
            for k in range(restored, n):
                pub.publish(pair_msg(cell, k, stamp_s=100.0 + k))
            wait_for(lambda: statuses and statuses[-1].n_measurements == n, 30, "all pairs")
            full_answers = self.answers(name, cell)
            check_answers(full_answers, expected_answers(cell))

            # Killed again and restarted: the same answers, bit for bit.
            node.send_signal(signal.SIGKILL)
            node.wait(timeout=15)
            statuses.clear()
            node = start_test_node(name, state_dir, log)
            wait_for(lambda: statuses and statuses[-1].model_valid
                     and statuses[-1].n_measurements == n, 30, "restored model")
            assert self.answers(name, cell) == full_answers
        finally:
            stop_process(node)
            log.close()
            self.ros.client.destroy_subscription(sub)
            self.ros.client.destroy_publisher(pub)
