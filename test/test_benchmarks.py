"""The soak's pass/fail checks (benchmarks/soak_report.py) on made-up results, and the in-process
memory benchmark on a small count. Pure: no rclpy, no timing assertions."""

import copy
import os
import subprocess
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "benchmarks"))

import soak_report  # noqa: E402


def results(published=1000, accepted=1000, journaled=1000, rejected=0, errors=()):
    sample = {"rss_mb": 100.0, "hwm_mb": 100.0, "threads": 20, "fds": 19, "load1": 1.0,
              "n_measurements": 0, "node_cpu_pct": 50.0, "soak_cpu_cores": 1.0,
              "machine_cpu_cores": 1.2}
    samples = [dict(sample, t=float(t), n_measurements=t * 200, rss_mb=100.0 + 0.001 * t)
               for t in range(6)]
    client = {"index": 0, "t": [0.1, 0.2, 0.3], "latency_s": [0.001, 0.002, 0.003],
              "n_errors": len(errors), "errors": list(errors), "exit_code": 0}
    return {"settings": {"duration_s": 5.0, "clients": 1, "rate": 200.0, "max_pairs": 0,
                         "think_s": 0.01, "call_timeout_s": 5.0, "sample_s": 1.0},
            "machine": {"cores": 2, "cpu": "x", "python": "3", "rclpy": "9", "rmw": "r"},
            "before": samples[0], "samples": samples, "final": samples[-1],
            "children": {"client0": client,
                         "streamer": {"published": published, "exit_code": 0}},
            "node_final_status": {"n_measurements": accepted, "n_rejected": rejected,
                                  "n_fiducials": 48},
            "node_exit_code": 0, "journal": {"measurements": journaled, "bytes": 1},
            "node_log_bytes": 0}


def test_a_clean_run_passes_every_check():
    summary = soak_report.summarise(results())
    assert all(summary["checks"].values()), summary["checks"]
    assert summary["latency"]["overall"]["calls"] == 3
    assert summary["latency"]["overall"]["p50_ms"] == pytest.approx(2.0)
    assert summary["rss_mb"]["slope_mb_per_h"] == pytest.approx(3.6)
    assert "errors: 0" in soak_report.markdown(results(), summary)


@pytest.mark.parametrize("change, failed", [
    ({"errors": [{"t": 1.0, "kind": "timeout", "message": "no answer"}]}, "no_errors"),
    ({"accepted": 999}, "nothing_lost"),
    ({"journaled": 999}, "nothing_lost"),
    ({"rejected": 1}, "nothing_rejected"),
    ({"published": 999, "accepted": 999, "journaled": 999}, "stream_complete"),
])
def test_each_kind_of_failure_fails_its_check(change, failed):
    summary = soak_report.summarise(results(**change))
    assert not summary["checks"][failed]
    assert [k for k, ok in summary["checks"].items() if not ok] == [failed]


def test_a_child_that_died_fails_the_run():
    data = copy.deepcopy(results())
    data["children"]["client0"] = {"fatal": "RuntimeError: no model", "exit_code": 1}
    summary = soak_report.summarise(data)
    assert summary["errors"] == 1
    assert not summary["checks"]["children_exit_0"]


def test_memory_benchmark_runs_in_process():
    run = subprocess.run([sys.executable, os.path.join(ROOT, "benchmarks", "bench_memory.py"),
                          "--count", "2000"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert "bytes per measurement" in run.stdout


def test_the_planner_cells_paired_summary_tells_a_tie_from_a_lead():
    """benchmarks/plan_cells.paired_summary on made-up curves: the planner 0.01 mm below random
    (with a little scatter) is a lead (tiny p, no count above); farthest-point offsets by seed
    of mean 0.5 µm against a scatter of 2-3 µm are a tie (p ~ 0.6); a count made 50 µm worse in one
    seed of six is above, with t 0.99 (mean 7.83, SE 7.89 µm)."""
    import numpy as np
    import plan_cells

    counts = np.arange(10, 61)
    base = np.linspace(0.2, 0.1, len(counts))
    far_off = np.array([0.003, -0.001, 0.002, -0.004, 0.001, 0.002])      # mean 0.5 µm
    rand_off = 0.01 + np.array([0.001, -0.001, 0.0, 0.0005, -0.0005, 0.0])
    runs = [{"planner": {"tre": list(base)}, "random": {"tre": list(base + rand_off[s])},
             "farthest": {"tre": list(base + far_off[s])}} for s in range(6)]
    grid, rand = plan_cells.paired_summary(runs, counts)
    assert grid.startswith("- planner - farthest, paired over 6 seeds: counts 11-19: "
                           "-0.50 ± 1.06 µm (p = 0.66); counts 20-60: -0.50 ± 1.06 µm "
                           "(p = 0.66)"), grid
    assert grid.endswith("counts above: 0, largest t there -")
    assert rand.startswith("- planner - random, paired over 6 seeds: counts 11-19: -10.00 ± 0.29 "
                           "µm (p = 3.8e-07)"), rand
    assert rand.endswith("counts above: 0, largest t there -")
    runs[0]["planner"]["tre"][5] += 0.05            # count 15: +7.8 µm, SE 7.9 µm
    grid = plan_cells.paired_summary(runs, counts)[0]
    assert grid.endswith("counts above: 1, largest t there 0.99"), grid
