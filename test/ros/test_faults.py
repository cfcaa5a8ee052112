"""Fault tests of registration_node as a separate process (docs/HARDENING.md): SIGKILL inside a
snapshot write, and a full disk for the journal (a file-size limit, and a tiny tmpfs where one
can be mounted). Restart always recovers every acknowledged measurement and never uses a
half-written snapshot. SIGKILL during ingestion: test_node_process.py::TestKillAndRestart.

DDS stays on loopback: test/conftest.py sets ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST and a
per-process ROS_DOMAIN_ID, which the node processes inherit.
"""

import os
import resource
import signal
import subprocess
import sys
import threading

import pytest

rclpy = pytest.importorskip("rclpy")
pytest.importorskip("rbc_registration_interfaces.msg")

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from rbc_registration_interfaces.msg import FiducialPair  # noqa: E402
from rbc_registration_interfaces.srv import CorrectTarget  # noqa: E402

from rbc_registration.pipeline.journal import Journal  # noqa: E402
from rbc_registration.pipeline.snapshot import SNAPSHOT_NAME, read_snapshot  # noqa: E402
from ros_helpers import (RosTestBase, make_cell, pair_msg, start_test_node,  # noqa: E402
                         stop_process, target_msg, wait_for)
from test_node_process import (check_answers, expected_answers, process_answers,  # noqa: E402
                               status_sub)

pytestmark = pytest.mark.ros
HEADER = {"working_frame": "tracker", "destination_frame": "world", "dimension": 3}
#: File-size limit of the journal in the rlimit case: about half of the 144 records fit, the
#: 12 kB snapshot never does.
FSIZE_LIMIT = 8000
#: Size of the tmpfs in the tmpfs case (3 pages): the journal fills it after ~100 records.
TMPFS_SIZE = "12k"


def limit_file_size():
    """preexec_fn: files of the node may not grow beyond FSIZE_LIMIT bytes; a write beyond it
    fails with EFBIG instead of killing the process with SIGXFSZ."""
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (FSIZE_LIMIT, FSIZE_LIMIT))


class LogPipe:
    """The node's output through a pipe into ``path`` (a pipe is not subject to the node's
    file-size limit)."""

    def __init__(self, path):
        self.path = path
        self._file = open(path, "ab")

    def start(self, proc):
        self._thread = threading.Thread(target=self._copy, args=(proc.stdout,), daemon=True)
        self._thread.start()

    def _copy(self, stream):
        for line in stream:
            self._file.write(line)
            self._file.flush()

    def join(self):
        self._thread.join(timeout=10)

    def text(self):
        with open(self.path, encoding="utf-8", errors="replace") as f:
            return f.read()

    def close(self):
        self._file.close()


def journal_indices(state_dir):
    """Indices k of the pairs in the journal (pair k has stamp 100 + k), and the load warnings."""
    journal = Journal(str(state_dir), HEADER)
    records, warnings = journal.load()
    journal.close()
    return [round(r.stamp_s - 100.0) for r in records], warnings


#: registration_node whose snapshot writes pause half way (a writer injected into the node).
PAUSED_NODE = (sys.executable, os.path.join(os.path.dirname(os.path.abspath(__file__)),
                                            "paused_snapshot_node.py"))


class TestFaults(RosTestBase):

    def publish(self, pub, cell, indices):
        for k in indices:
            pub.publish(pair_msg(cell, k, stamp_s=100.0 + k))

    def test_sigkill_inside_a_snapshot_write(self, tmp_path):
        cell = make_cell(seed=7)
        n = len(cell["fid"])
        half = n // 2
        state_dir = tmp_path / "state"
        snapshot = state_dir / SNAPSHOT_NAME
        name = f"reg_snapkill_{os.getpid()}"
        statuses, sub = status_sub(self.ros, name)
        pub = self.ros.client.create_publisher(FiducialPair, f"/{name}/fiducial_pairs", 1000)
        log = open(tmp_path / "node.log", "w")
        node = start_test_node(name, state_dir, log, status_period=0.05)
        try:
            # 1. Half the pairs, a model and a complete snapshot of it; a clean stop.
            wait_for(lambda: pub.get_subscription_count() > 0, 30, "the node's subscription")
            self.publish(pub, cell, range(half))
            wait_for(lambda: statuses and statuses[-1].n_measurements == half, 30, "half")
            process_answers(self.ros, name, cell)
            stop_process(node)
            assert read_snapshot(str(snapshot))["n_measurements"] == half

            # 2. Restart with a snapshot writer that pauses: the rebuild after restoring the
            #    journal stops half way through writing the snapshot's temporary file.
            #    Meanwhile the node keeps accepting (and journaling) the other half and
            #    answering targets.
            marker = tmp_path / "paused"
            statuses.clear()
            node = start_test_node(name, state_dir, log, command=(*PAUSED_NODE, str(marker)),
                                   status_period=0.05)
            wait_for(marker.exists, 30, "the snapshot write to pause")
            wait_for(lambda: pub.get_subscription_count() > 0, 30, "the node's subscription")
            self.publish(pub, cell, range(half, n))
            wait_for(lambda: statuses and statuses[-1].n_measurements == n, 30, "all pairs")
            r = self.ros.call(CorrectTarget, f"/{name}/correct_target",
                              CorrectTarget.Request(target=target_msg(cell["targets"][0])), 30)
            assert r.success, r.message
            tmp = marker.read_text().strip()
            with pytest.raises(ValueError, match="not valid JSON"):
                read_snapshot(tmp)                     # really half-written
            node.send_signal(signal.SIGKILL)           # inside the write
            node.wait(timeout=15)
            assert os.path.exists(tmp)
            assert read_snapshot(str(snapshot))["n_measurements"] == half   # old one: whole
            # Make the snapshot itself corrupt too (as a non-atomic writer or a bad disk
            # would): the node must not trust it either.
            snapshot.write_bytes(snapshot.read_bytes()[:100])

            # 3. Restart: both files are set aside with a warning; the model comes from the
            #    journal, with every acknowledged measurement: the model of all n pairs.
            statuses.clear()
            node = start_test_node(name, state_dir, log, status_period=0.05)
            wait_for(lambda: statuses and statuses[-1].model_valid
                     and statuses[-1].n_measurements == n, 30, "the restored model")
            check_answers(process_answers(self.ros, name, cell), expected_answers(cell))
            wait_for(lambda: snapshot.exists() and read_snapshot(str(snapshot))[
                "n_measurements"] == n, 30, "a new, complete snapshot")
            assert not os.path.exists(tmp)
            assert [f for f in os.listdir(state_dir) if ".tmp." in f] == []
        finally:
            stop_process(node)
            log.close()
            self.ros.client.destroy_subscription(sub)
            self.ros.client.destroy_publisher(pub)
        text = (tmp_path / "node.log").read_text()
        assert "removed calibration.json.tmp." in text
        assert "a snapshot write was interrupted" in text
        assert "is not a valid snapshot (not valid JSON" in text

    @pytest.mark.parametrize("limit", ["rlimit", "tmpfs"])
    def test_full_disk_for_the_journal(self, tmp_path, limit):
        cell = make_cell(seed=9)
        n = len(cell["fid"])
        state_dir = tmp_path / "state"
        state_dir.mkdir()
        popen = {"stdout": subprocess.PIPE}
        if limit == "rlimit":
            popen["preexec_fn"] = limit_file_size
        else:
            mount = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={TMPFS_SIZE}", "tmpfs",
                                    str(state_dir)], capture_output=True, text=True)
            if mount.returncode != 0:
                pytest.skip(f"cannot mount a tmpfs here ({mount.stderr.strip()}); the rlimit "
                            f"case covers a full disk")
        name = f"reg_full_{limit}_{os.getpid()}"
        statuses, sub = status_sub(self.ros, name)
        diagnostics = []
        diag_sub = self.ros.client.create_subscription(DiagnosticArray, "/diagnostics",
                                                       diagnostics.append, 100)
        pub = self.ros.client.create_publisher(FiducialPair, f"/{name}/fiducial_pairs", 1000)
        log = LogPipe(tmp_path / "node.log")
        node = None
        try:
            # 1. The disk fills up while the pairs stream in: those that cannot be journaled
            #    are not accepted, and the node says so.
            node = start_test_node(name, state_dir, ros_args=["--disable-external-lib-logs"],
                              popen=popen, status_period=0.05)
            log.start(node)
            wait_for(lambda: pub.get_subscription_count() > 0, 30, "the node's subscription")
            self.publish(pub, cell, range(n))
            wait_for(lambda: statuses and statuses[-1].n_measurements
                     + statuses[-1].n_journal_failures == n, 30, "every pair handled")
            status = statuses[-1]
            acknowledged = status.n_measurements
            print(f"{limit}: {acknowledged} of {n} acknowledged, "
                  f"{status.n_journal_failures} refused: {status.message}")
            assert 0 < acknowledged < n and status.n_journal_failures == n - acknowledged
            assert status.message.startswith(f"journal write failed, {n - acknowledged} "
                                             f"record(s) not accepted: ")
            error = "File too large" if limit == "rlimit" else "No space left on device"
            assert error in status.message

            def journal_error():
                return [s for d in diagnostics for s in d.status
                        if s.name == f"/{name}: registration"
                        and s.level == DiagnosticStatus.ERROR and error in s.message]
            wait_for(journal_error, 30, "/diagnostics ERROR")

            # 2. It keeps answering from the model it has (the acknowledged measurements).
            before = process_answers(self.ros, name, cell)
            assert all(a[0] for a in before)
            node.send_signal(signal.SIGKILL)
            node.wait(timeout=15)
            log.join()

            # 3. Space again; the journal holds exactly the acknowledged measurements, whole.
            if limit == "tmpfs":
                subprocess.run(["mount", "-o", "remount,size=4m", str(state_dir)], check=True)
            accepted, warnings = journal_indices(state_dir)
            assert warnings == [] and len(accepted) == acknowledged
            statuses.clear()
            node = start_test_node(name, state_dir, ros_args=["--disable-external-lib-logs"],
                              popen={"stdout": subprocess.PIPE}, status_period=0.05)
            log.start(node)
            wait_for(lambda: statuses and statuses[-1].model_valid, 30, "the restored model")
            assert statuses[-1].n_measurements == acknowledged
            after = process_answers(self.ros, name, cell)
            assert after == before
            check_answers(after, expected_answers(cell, accepted))

            # 4. The refused pairs, sent again, complete the model.
            missing = [k for k in range(n) if k not in set(accepted)]
            self.publish(pub, cell, missing)
            wait_for(lambda: statuses and statuses[-1].n_measurements == n, 30, "all pairs")
            check_answers(process_answers(self.ros, name, cell),
                          expected_answers(cell, accepted + missing))
            assert statuses[-1].n_journal_failures == 0
        finally:
            if node is not None:
                stop_process(node)
                log.join()
            log.close()
            self.ros.client.destroy_subscription(sub)
            self.ros.client.destroy_subscription(diag_sub)
            self.ros.client.destroy_publisher(pub)
            if limit == "tmpfs" and subprocess.run(["umount", str(state_dir)]).returncode:
                subprocess.run(["umount", "-l", str(state_dir)])   # busy: detach it anyway
        text = log.text()
        assert "journal write failed, measurement NOT accepted" in text
        if limit == "rlimit":
            assert "calibration snapshot not written" in text
