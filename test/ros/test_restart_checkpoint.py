"""A node process killed with SIGKILL restarts from its checkpoint (pipeline/checkpoint.py): the
sums of the records the checkpoint covers are loaded, only the journal's tail is replayed, every
acknowledged pair is back and the answers are those of the live node; a corrupt checkpoint is
named and the journal replayed whole, with the same answers."""

import json
import os
import signal
import time

import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("rbc_registration_interfaces.msg")

from rbc_registration.pipeline.checkpoint import CHECKPOINT_NAME  # noqa: E402
from rbc_registration_interfaces.msg import FiducialPair  # noqa: E402
from rbc_registration_interfaces.srv import CorrectTarget  # noqa: E402

from ros_helpers import (RosTestBase, answer_key, make_cell, pair_msg,  # noqa: E402
                         start_test_node, stop_process, target_msg, wait_for)
from test_node_process import (check_answers, expected_answers, recompute_and_wait,  # noqa: E402
                               status_sub)

pytestmark = pytest.mark.ros


def checkpoint_records(state_dir) -> int:
    """The journal records the checkpoint of ``state_dir`` covers (-1: none)."""
    try:
        text = (state_dir / CHECKPOINT_NAME).read_text()
    except FileNotFoundError:
        return -1
    return json.loads(text.split("\n", 1)[1])["journal"]["records"]


class TestRestartFromTheCheckpoint(RosTestBase):
    def answers(self, name, cell):
        return [answer_key(self.ros.call(CorrectTarget, f"/{name}/correct_target",
                                         CorrectTarget.Request(target=target_msg(t)), 30))
                for t in cell["targets"]]

    def kill_and_restart(self, node, name, state_dir, log, statuses, n):
        node.send_signal(signal.SIGKILL)
        node.wait(timeout=15)
        statuses.clear()
        node = start_test_node(name, state_dir, log)
        wait_for(lambda: statuses and statuses[-1].model_valid
                 and statuses[-1].n_measurements == n, 60, "the restored model")
        return node

    def test_kill_9_then_restart_loads_the_checkpoint_and_replays_the_tail(self, tmp_path):
        cell = make_cell(seed=7, repeats=3)
        n, half = len(cell["fid"]), len(cell["fid"]) // 2
        state_dir = tmp_path / "state"
        name = f"reg_ckpt_{os.getpid()}"
        log = open(tmp_path / "node.log", "w")
        # A long debounce: the pairs after the first checkpoint stay in the journal's tail.
        node = start_test_node(name, state_dir, log, debounce_period=30.0)
        statuses, sub = status_sub(self.ros, name)
        pub = self.ros.client.create_publisher(FiducialPair, f"/{name}/fiducial_pairs", 1000)
        try:
            wait_for(lambda: pub.get_subscription_count() > 0, 30, "the node's subscription")
            for k in range(half):
                pub.publish(pair_msg(cell, k, stamp_s=100.0 + k))
            wait_for(lambda: statuses and statuses[-1].n_measurements == half, 30, "half")
            recompute_and_wait(self.ros, name)
            wait_for(lambda: checkpoint_records(state_dir) == half, 30, "the checkpoint")
            for k in range(half, n):
                pub.publish(pair_msg(cell, k, stamp_s=100.0 + k))
                time.sleep(0.002)
            wait_for(lambda: statuses and statuses[-1].n_measurements == n, 30, "every pair")
            assert checkpoint_records(state_dir) == half      # no rebuild yet: a tail of n - half

            node = self.kill_and_restart(node, name, state_dir, log, statuses, n)
            log.flush()
            text = (tmp_path / "node.log").read_text()
            assert (f"restored {n} measurements (the sums of the first {half} records from the "
                    f"checkpoint, the journal's last {n - half} replayed)") in text, text
            check_answers(self.answers(name, cell), expected_answers(cell))

            # The live node's answers, then kill -9 and restart: the same, bit for bit.
            wait_for(lambda: checkpoint_records(state_dir) == n, 30, "the checkpoint of all")
            live = self.answers(name, cell)
            node = self.kill_and_restart(node, name, state_dir, log, statuses, n)
            assert self.answers(name, cell) == live

            # A corrupt checkpoint: named, the journal replayed whole, the same answers.
            path = state_dir / CHECKPOINT_NAME
            data = bytearray(path.read_bytes())
            data[data.index(b'"n_measurements":') + 17] ^= 1
            path.write_bytes(bytes(data))
            node = self.kill_and_restart(node, name, state_dir, log, statuses, n)
            log.flush()
            text = (tmp_path / "node.log").read_text()
            assert "is corrupt (its checksum does not hold): not used, the journal is " \
                   "replayed whole" in text, text
            assert self.answers(name, cell) == live
        finally:
            stop_process(node)
            log.close()
            self.ros.client.destroy_subscription(sub)
            self.ros.client.destroy_publisher(pub)
