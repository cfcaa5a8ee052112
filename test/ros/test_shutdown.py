"""Ctrl-C (SIGINT to the process group, as a terminal sends it) while the node rebuilds a model:
rclpy's handler shuts the context down at once while the rebuild goes on in the recompute
thread; the node then publishes nothing more and stops with status 0, without an ``RCLError``
traceback from that thread or a ``recompute failed`` line."""

import os
import signal
import time

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rbc_registration_interfaces.msg")

from rbc_registration.core.measurements.accumulator import FiducialAccumulator  # noqa: E402
from rbc_registration.pipeline.journal import Journal  # noqa: E402
from ros_helpers import start_test_node, wait_for  # noqa: E402

pytestmark = pytest.mark.ros

#: Enough fiducials that the first model (kriging, cross-validated) takes seconds to build;
#: ``rebuild_worker: auto`` builds it in the child process from 1000 on.
FIDUCIALS = 1000
HEADER = {"working_frame": "tracker", "destination_frame": "world", "dimension": 3}


def _journal(state_dir, n):
    """A state_dir whose journal holds one pair of each of ``n`` fiducials (a 2 m cell, metres,
    a 1 mm smooth bias): the node's first rebuild, from the journal, starts with the node."""
    rng = np.random.default_rng(0)
    destination = rng.uniform(0.0, 2.0, (n, 3))
    working = destination + 1e-3 * np.sin(3 * destination) + rng.normal(0, 2e-5, (n, 3))
    accumulator = FiducialAccumulator(3, "tracker", "world", 0.005)
    journal = Journal(str(state_dir), HEADER)
    journal.load()
    journal.append_many(accumulator.prepare(f"F{k:04d}", working[k], destination[k],
                                            stamp_s=1000.0 + k) for k in range(n))
    journal.close()


@pytest.mark.parametrize("rebuild_worker", ["thread", "process"])
def test_ctrl_c_during_a_rebuild_is_a_quiet_stop(tmp_path, rebuild_worker):
    state_dir = tmp_path / "state"
    state_dir.mkdir()
    _journal(state_dir, FIDUCIALS)
    log_path = tmp_path / "node.log"
    with open(log_path, "w") as log:
        proc = start_test_node(f"reg_ctrl_c_{os.getpid()}", state_dir, log,
                               rebuild_worker=rebuild_worker,
                               popen={"start_new_session": True})
        try:
            wait_for(lambda: "registering" in log_path.read_text(), 120, "the node's start")
            time.sleep(0.5)                 # the first rebuild is under way
            os.killpg(proc.pid, signal.SIGINT)
            rc = proc.wait(timeout=120)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    text = log_path.read_text()
    # the signal came during the rebuild: its model was never served, so never saved
    assert not (state_dir / "calibration.json").exists(), text
    assert rc == 0, text
    assert "Traceback" not in text and "RCLError" not in text, text
    assert "recompute failed" not in text and "context is invalid" not in text, text
