"""The soak (benchmarks/soak.py) in short: the node, a streamer at 200 pairs/s and 4 client
processes calling ``~/correct_target`` for 15 s, all separate processes on loopback. No call
may fail, every published pair must be accepted and journaled, the results must be written.
Nothing here asserts speed; memory only against gross growth.

The 10-minute run is a documented command (benchmarks/RESULTS.md, "Soak"):
``source scripts/env.sh && python benchmarks/soak.py --duration 600``.
"""

import json
import os
import subprocess
import sys

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("rbc_registration_interfaces.msg")

pytestmark = pytest.mark.ros
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SOAK = os.path.join(ROOT, "benchmarks", "soak.py")
DURATION = 15


@pytest.fixture(scope="module")
def soak(tmp_path_factory):
    out = tmp_path_factory.mktemp("soak")
    # Its own ROS domain (from this test process's domain, so not the suite's own one).
    domain = int(os.environ.get("ROS_DOMAIN_ID", "1")) % 101 + 1
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    run = subprocess.run([sys.executable, SOAK, "--duration", str(DURATION), "--clients", "4",
                          "--sample", "1", "--out", str(out), "--domain", str(domain)],
                         env=env, capture_output=True, text=True, timeout=DURATION + 300)
    logs = "".join(f"\n--- {p.name}\n{p.read_text()[-2000:]}"
                   for p in sorted((out / "logs").glob("*.log"))) if (out / "logs").exists() else ""
    return run, out, run.stdout + run.stderr + logs


def test_the_soak_ends_with_every_check_passed(soak):
    run, out, log = soak
    assert run.returncode == 0, log


def test_results_are_written(soak):
    run, out, log = soak
    for name in ("soak.json", "soak.md", "soak.png"):
        assert (out / name).stat().st_size > 0, f"{name} missing\n{log}"
    assert "errors: 0" in (out / "soak.md").read_text()


def test_no_call_failed_and_every_client_called(soak):
    run, out, log = soak
    results = json.loads((out / "soak.json").read_text())
    summary = results["summary"]
    assert summary["errors"] == 0, summary["error_kinds"]
    clients = [k for k in results["children"] if k.startswith("client")]
    assert len(clients) == 4
    for k in clients:
        assert summary["latency"][k]["calls"] > 0, k


def test_every_published_pair_is_accepted_and_journaled(soak):
    run, out, log = soak
    pairs = json.loads((out / "soak.json").read_text())["summary"]["pairs"]
    assert pairs["published"] == pairs["expected"] == 200 * DURATION
    assert pairs["accepted"] == pairs["journal_measurements"] == pairs["published"]
    assert pairs["rejected"] == 0 and pairs["lost"] == 0


def test_memory_does_not_grow_grossly(soak):
    run, out, log = soak
    rss = json.loads((out / "soak.json").read_text())["summary"]["rss_mb"]
    assert rss["end"] - rss["before_stream"] < 50.0, rss
