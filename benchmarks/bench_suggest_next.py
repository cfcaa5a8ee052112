"""Time of the node's ``~/suggest_next`` work on the executor (issue 13): the plan from the
served model and the error model the planning thread made (``pipeline.planning.suggest``), and
the planning thread's work per model (``planning_state``).

Run: ``.venv/bin/python benchmarks/bench_suggest_next.py [--repeats 7] [--candidates 500]``.

RA-like cell (seed 3) in metres, single measurements, sigma given 0.11 mm, J = 277 fiducials;
candidates uniform in the cell's bounding box; the work volume or the 80 targets, count 1 and
10. Cases run in turn, round after round, so machine load hits all alike; min and median over
the rounds. 1 BLAS thread (as the node runs). Prints Markdown.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from rbc_registration.core.measurements.accumulator import FiducialAccumulator  # noqa: E402
from rbc_registration.core.synthetic.cells import make_cell  # noqa: E402
from rbc_registration.pipeline.planning import planning_state, suggest  # noqa: E402
from rbc_registration.pipeline.settings import Settings  # noqa: E402
from rbc_registration.pipeline.state import build_state  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--candidates", type=int, default=500)
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args(argv)
    cell = make_cell("RA", seed=3)
    settings = Settings.from_mapping({"dimension": 2, "sigma": 0.11e-3,
                                      "max_candidates": max(args.candidates, 80)})
    acc = FiducialAccumulator(2, "tracker", "world", 1e-6, 0.0)
    for fid, m, truth in zip(cell.fiducial_ids, cell.fiducial_measurements, cell.fiducial_truth):
        acc.add(fid, m[0] / 1000, truth / 1000)
    state = build_state(acc.fiducial_set(), settings, 1)
    times = {"planning_state (per model, planning thread)": []}
    lo, hi = cell.fiducial_means.min(0) / 1000, cell.fiducial_means.max(0) / 1000
    cand = np.random.default_rng(0).uniform(lo, hi, (args.candidates, 2))
    cases = {(where, count): (tg, count) for where, tg in
             (("work volume", None), ("80 targets", cell.target_means / 1000))
             for count in (1, 10)}
    for _ in range(args.repeats):
        t = time.perf_counter()
        planning = planning_state(state)
        times["planning_state (per model, planning thread)"].append(time.perf_counter() - t)
        for key, (tg, count) in cases.items():
            t = time.perf_counter()
            suggest(planning, state, settings, cand, tg, count)
            times.setdefault(key, []).append(time.perf_counter() - t)
    print(f"J = {len(cell.fiducial_ids)}, {args.candidates} candidates, {args.repeats} rounds, "
          f"load average {os.getloadavg()[0]:.1f}\n")
    print("| what | error taken at | count | min | median |\n|---|---|---|---|---|")
    for key, ts in times.items():
        what, where, count = (("suggest",) + key) if isinstance(key, tuple) else (key, "-", "-")
        print(f"| {what} | {where} | {count} | {min(ts) * 1e3:.0f} ms | "
              f"{statistics.median(ts) * 1e3:.0f} ms |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
