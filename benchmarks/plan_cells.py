"""The measurement planner on the synthetic RA-like (2D) and A-like (3D) cells, as a user runs it.

Run: ``.venv/bin/python benchmarks/plan_cells.py [--seeds 10] [--first-seed 0] [--cells RA,A]
[--json out.json]`` (``--cells robot``: the grouped robot cell, :func:`run_robot`); the cells
can run in parallel (one ``--cells`` and ``--json`` each) and be reported together with
``--load ra.json,a.json``.

Per cell and seed, single measurements (the first measurement of every fiducial and target; the
truth known), sigma unknown, the model's defaults (``build_model`` with
``ModelConfig(dimension=d)``: the ``cv`` decision, kriging hyper-parameters fitted with the
noise): start from 10 fiducials drawn at random from the fiducial set, then add fiducials from
the remaining fiducial locations (working frame) in

- ``planner``: the plan's suggestions in batches of :data:`BATCH` (the cell's targets given, the
  model rebuilt and the plan made again after each batch, as a user measures);
- ``random``: a random order;
- ``farthest``: a space-filling order: each next fiducial is the remaining location farthest
  from the fiducials so far (farthest-point).

The actual median TRE of the targets against the truth is taken at :data:`COUNTS` with the model
the planner serves (``TargetCorrections.destination``). The planner's order is then followed with
the default rules (``PlanConfig()``: within 10 % of every hole measured) until its plan says
``enough``, measuring each batch only up to ``enough_after`` when the plan gives it; the TRE there
is set against the TRE with every fiducial and the count at which the farthest-point order first
reaches it. At :data:`CHECK_COUNTS` the plan's (calibrated) expected median target error is set
against the actual one, with the error model check
(:mod:`rbc_registration.core.planning.model_check`).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import scipy.stats  # noqa: E402

from rbc_registration.core.answers import TargetEvaluation  # noqa: E402
from rbc_registration.core.model import ModelConfig, RbcModel, build_model  # noqa: E402
from rbc_registration.core.planning.model_planner import plan_from_model  # noqa: E402
from rbc_registration.core.planning.planner import PlanConfig  # noqa: E402
from rbc_registration.core.synthetic.cells import make_cell  # noqa: E402

ORDERS = ("planner", "random", "farthest")
COUNTS = tuple(range(10, 61, 5))
CHECK_COUNTS = (10, 15, 20, 30, 40, 60)
BATCH = 5
START = 10


def build(x: np.ndarray, y: np.ndarray, dim: int) -> RbcModel:
    """The model a user gets with the defaults and sigma unknown."""
    return build_model(x, y, ModelConfig(dimension=dim))


class Cell:
    """One instantaneous dataset of a synthetic cell."""

    def __init__(self, name: str, seed: int) -> None:
        c = make_cell(name, seed)
        self.name, self.dim, self.sigma = name, c.spec.dimension, c.spec.sigma
        self.x = np.array([m[0] for m in c.fiducial_measurements])
        self.y = c.fiducial_truth
        self.tw = np.array([m[0] for m in c.target_measurements])
        self.td = c.target_truth

    def model(self, idx) -> RbcModel:
        idx = list(idx)
        return build(self.x[idx], self.y[idx], self.dim)

    def tre(self, model: RbcModel) -> float:
        """Median TRE of the targets at the point the model serves."""
        served = model.correct(self.tw).destination
        return float(np.median(np.linalg.norm(served - self.td, axis=1)))

    def tre_kriging(self, model: RbcModel) -> float:
        """Median TRE of the targets corrected by kriging (what the plan's errors assume)."""
        point = TargetEvaluation(model, self.tw).registered("kriging")
        return float(np.median(np.linalg.norm(point - self.td, axis=1)))


def farthest_point_order(points: np.ndarray, start: list[int], count: int) -> list[int]:
    """``start`` followed by ``count`` more indices, each the farthest from those so far."""
    order = list(start)
    dist = np.min(np.linalg.norm(points[:, None, :] - points[None, order, :], axis=2), axis=1)
    for _ in range(count):
        k = int(np.argmax(dist))
        order.append(k)
        dist = np.minimum(dist, np.linalg.norm(points - points[k], axis=1))
    return order


def run_planner(cell: Cell, start_idx: list[int], config: PlanConfig) -> dict:
    """Follow the planner in batches to the last of :data:`COUNTS` and on to its ``enough``."""
    chosen = list(start_idx)
    tre, check, stop = {}, {}, None
    n_all = len(cell.x)
    while True:
        j = len(chosen)
        m = cell.model(chosen)
        rest = np.setdiff1d(np.arange(n_all), chosen)
        if j in COUNTS:
            tre[j] = cell.tre(m)
        if len(rest) == 0:
            stop = stop or {"count": j, "tre": cell.tre(m), "rule": "all measured"}
            break
        p = plan_from_model(m, cell.x[rest], cell.tw, count=min(BATCH, len(rest)),
                            config=config)
        if j in CHECK_COUNTS:
            mc = p.model_check
            check[j] = {"expected": p.expected_now, "actual": tre[j],
                        "kriging": cell.tre_kriging(m), "method": m.decision.method,
                        "with_all": p.expected_with_all, "ratio": mc.ratio,
                        "trustworthy": mc.trustworthy}
        if p.enough and stop is None:
            stop = {"count": j, "tre": tre.get(j, cell.tre(m)), "rule": p.enough_rule,
                    "expected": p.expected_now, "with_all": p.expected_with_all}
        if stop is not None and j >= COUNTS[-1]:
            break
        take = BATCH if stop is not None or not p.enough_after else p.enough_after
        if j < COUNTS[-1]:                  # land on every count of COUNTS
            take = min(take, min(c for c in COUNTS if c > j) - j)
        chosen += [int(rest[k]) for k in p.ranked_candidates[:take]]
    return {"tre": [tre[j] for j in COUNTS], "check": check, "stop": stop}


def run_cell(name: str, seed: int, config: PlanConfig) -> dict:
    cell = Cell(name, seed)
    rng = np.random.default_rng([seed, 13])
    n = len(cell.x)
    perm = [int(k) for k in rng.permutation(n)]
    start_idx = perm[:START]
    t0 = time.perf_counter()
    every = cell.model(range(n))
    out = {"all_tre": cell.tre(every), "all_kriging": cell.tre_kriging(every), "n_fiducials": n}
    out["planner"] = run_planner(cell, start_idx, config)
    out["random"] = {"tre": [cell.tre(cell.model(perm[:j])) for j in COUNTS]}
    far = farthest_point_order(cell.x, start_idx, n - START)
    out["farthest"] = {"tre": [cell.tre(cell.model(far[:j])) for j in COUNTS]}
    # the count at which the farthest-point order first reaches the planner's TRE at its stop
    goal, reach = out["planner"]["stop"]["tre"], None
    for j in range(START, n + 1):
        if cell.tre(cell.model(far[:j])) <= goal:
            reach = j
            break
    out["farthest_reach"] = reach
    out["seconds"] = time.perf_counter() - t0
    return out


def paired(runs: list[dict], order: str) -> list[tuple[float, float, float]]:
    """Per count: mean of (planner - order) over the seeds, its standard error, the p-value."""
    mine = np.array([r["planner"]["tre"] for r in runs])
    diff = mine - np.array([r[order]["tre"] for r in runs])
    se = diff.std(axis=0, ddof=1) / np.sqrt(len(runs))
    p = [scipy.stats.ttest_1samp(diff[:, i], 0.0).pvalue for i in range(diff.shape[1])]
    return [(float(diff[:, i].mean()), float(se[i]), float(p[i])) for i in range(diff.shape[1])]


#: The ranges of counts :func:`paired_summary` averages over.
PAIRED_RANGES = ((11, 19), (20, 60))


def paired_summary(runs: list[dict], counts: np.ndarray,
                   orders: tuple[str, ...] = ("farthest", "random")) -> list[str]:
    """The planner against each fixed order, paired by seed: per range of counts, the mean over
    the seeds of (planner - order) averaged over the range's counts, its standard error, a
    two-sided one-sample t-test p-value, and the largest t of a count where the planner's mean is
    above (a t near 1 is a tie; 2 or more would be a real loss)."""
    mine = np.array([r["planner"]["tre"] for r in runs])
    lines = []
    for order in orders:
        diff = mine - np.array([r[order]["tre"] for r in runs])
        se = diff.std(axis=0, ddof=1) / np.sqrt(len(runs))
        t = [diff[:, i].mean() / se[i] for i in range(len(counts))
             if diff[:, i].mean() > 0 and se[i] > 0]
        parts = []
        for lo, hi in PAIRED_RANGES:
            sel = (counts >= lo) & (counts <= hi)
            if not sel.any():
                continue
            per_seed = diff[:, sel].mean(axis=1)
            p = scipy.stats.ttest_1samp(per_seed, 0.0).pvalue
            parts.append(f"counts {max(lo, int(counts[0]))}-{min(hi, int(counts[-1]))}: "
                         f"{per_seed.mean() * 1e3:+.2f} "
                         f"± {per_seed.std(ddof=1) / np.sqrt(len(runs)) * 1e3:.2f} µm "
                         f"(p = {p:.2g})")
        lines.append(f"- planner - {order}, paired over {len(runs)} seeds: " + "; ".join(parts)
                     + f"; counts above: {len(t)}, largest t there "
                     + (f"{max(t):.2f}" if t else "-"))
    return lines


def report(name: str, runs: list[dict]) -> list[str]:
    curves = {o: np.mean([r[o]["tre"] for r in runs], axis=0) for o in ORDERS}
    vs_random, vs_far = paired(runs, "random"), paired(runs, "farthest")
    lines = [f"### {name}: mean over {len(runs)} seeds of the median target TRE (mm)", "",
             "| fiducials | planner | random | farthest | planner - random (± SE) | "
             "planner - farthest (± SE, p) |", "|---|---|---|---|---|---|"]
    for i, j in enumerate(COUNTS):
        a, b = vs_random[i], vs_far[i]
        lines.append(f"| {j} | " + " | ".join(f"{curves[o][i]:.4f}" for o in ORDERS)
                     + f" | {a[0]:+.4f} ± {a[1]:.4f} | {b[0]:+.4f} ± {b[1]:.4f}, "
                       f"p = {b[2]:.2g} |")
    above_r = [j for j, a in zip(COUNTS, vs_random) if a[0] > 0]
    above_f = [j for j, b in zip(COUNTS, vs_far) if b[0] > 0 and b[2] < 0.05]
    lines += ["", f"- counts where the planner's mean is above random's: "
              f"{', '.join(map(str, above_r)) or 'none'}; significantly above farthest-point "
              f"(paired, p < 0.05): {', '.join(map(str, above_f)) or 'none'}"]
    lines += paired_summary(runs, np.array(COUNTS))
    stop = [r["planner"]["stop"] for r in runs]
    count = np.array([s["count"] for s in stop])
    ratio = np.array([s["tre"] / r["all_tre"] for s, r in zip(stop, runs)])
    reach = [r["farthest_reach"] for r in runs]
    rules = {}
    for s in stop:
        rules[s["rule"]] = rules.get(s["rule"], 0) + 1
    lines += ["", f"First `enough` with the defaults (within 10 %), planner order; mean "
              f"[min-max] over the seeds; all fiducials: {runs[0]['n_fiducials']}.", "",
              "| enough at | TRE there (mm) | TRE, every fiducial (mm) | there / every | "
              "farthest-point reaches that TRE at | rule |", "|---|---|---|---|---|---|",
              f"| {count.mean():.1f} [{count.min()}-{count.max()}] | "
              f"{np.mean([s['tre'] for s in stop]):.4f} | "
              f"{np.mean([r['all_tre'] for r in runs]):.4f} | {ratio.mean():.3f} "
              f"[{ratio.min():.3f}-{ratio.max():.3f}] | "
              + (f"{np.mean([v for v in reach if v]):.1f} [{min(v for v in reach if v)}-"
                 f"{max(v for v in reach if v)}]" if any(reach) else "-")
              + (f" (not reached in {sum(v is None for v in reach)})" if None in reach else "")
              + f" | {', '.join(f'{k} {v}' for k, v in rules.items())} |",
              "", "Expected (the plan's, calibrated) against actual median target error, planner "
              "order, mean over the seeds:", "",
              "| fiducials | expected | actual (served) | expected / actual (mean of the seeds' "
              "ratios) | actual, kriging-corrected | expected / kriging-corrected | served "
              "kriging | calibration (cross-validated / expected held-out) | trusted |",
              "|---|---|---|---|---|---|---|---|---|"]
    for j in CHECK_COUNTS:
        c = [r["planner"]["check"][str(j)] if str(j) in r["planner"]["check"]
             else r["planner"]["check"][j] for r in runs]
        kr = [x.get("kriging", math.nan) for x in c]
        lines.append(f"| {j} | {np.mean([x['expected'] for x in c]):.4f} | "
                     f"{np.mean([x['actual'] for x in c]):.4f} | "
                     f"{np.mean([x['expected'] / x['actual'] for x in c]):.3f} | "
                     f"{np.mean(kr):.4f} | "
                     f"{np.mean([x['expected'] / k for x, k in zip(c, kr)]):.3f} | "
                     f"{sum(x.get('method') == 'kriging' for x in c)} of {len(c)} | "
                     f"{np.mean([x['ratio'] for x in c]):.3f} | "
                     f"{sum(x['trustworthy'] for x in c)} of {len(c)} |")
    return lines


#: Robot cell (``--cells robot``): poses in the pool, reflectors kept per pose, the poses
#: measured first (at random), the poses per batch, and the pose counts reported.
ROBOT_POSES = 60
ROBOT_PER_POSE = 3
ROBOT_START = 4
ROBOT_BATCH = 2
ROBOT_COUNTS = (4, 6, 8, 10, 12, 14, 16, 20, 24, 30)


class RobotPlan:
    """A grouped robot cell (:func:`rbc_registration.core.synthetic.structure.make_robot_cell`,
    :data:`ROBOT_POSES` poses of exactly :data:`ROBOT_PER_POSE` reflectors, one measurement
    each): a candidate is a pose, measured as a whole."""

    def __init__(self, seed: int) -> None:
        from rbc_registration.core.synthetic.structure import make_robot_cell

        c = make_robot_cell(seed, poses=ROBOT_POSES, targets=40)
        keep = [k for k, g in enumerate(c.fiducial_groups)
                if c.fiducial_groups[:k].count(g) < ROBOT_PER_POSE]
        self.x, self.y = c.working[keep], c.destination[keep]
        self.groups = [c.fiducial_groups[k] for k in keep]
        self.poses = list(dict.fromkeys(self.groups))
        self.tw, self.td = c.target_working, c.target_truth

    def members(self, poses) -> list[int]:
        chosen = set(poses)
        return [k for k, g in enumerate(self.groups) if g in chosen]

    def model(self, poses) -> RbcModel:
        idx = self.members(poses)
        return build_model(self.x[idx], self.y[idx], ModelConfig(dimension=3),
                           groups=[self.groups[k] for k in idx])

    def tre(self, model: RbcModel) -> float:
        served = model.correct(self.tw).destination
        return float(np.median(np.linalg.norm(served - self.td, axis=1)))


def run_robot(seed: int, config: PlanConfig) -> dict:
    """Planner by pose (batches of :data:`ROBOT_BATCH` poses, re-planned) against random poses,
    the median target TRE at :data:`ROBOT_COUNTS` poses."""
    cell = RobotPlan(seed)
    rng = np.random.default_rng([seed, 17])
    perm = [cell.poses[k] for k in rng.permutation(len(cell.poses))]
    chosen = perm[:ROBOT_START]
    t0 = time.perf_counter()
    tre = {}
    while len(chosen) <= ROBOT_COUNTS[-1]:
        m = cell.model(chosen)
        if len(chosen) in ROBOT_COUNTS:
            tre[len(chosen)] = cell.tre(m)
        rest = [k for k, g in enumerate(cell.groups) if g not in set(chosen)]
        take = min(ROBOT_BATCH, min([c for c in ROBOT_COUNTS if c > len(chosen)]
                                    + [ROBOT_COUNTS[-1] + 1]) - len(chosen))
        p = plan_from_model(m, cell.x[rest], cell.tw, count=take, config=config,
                            groups=[cell.groups[k] for k in rest])
        chosen = chosen + [p.unit_labels[u] for u in p.sequence]
    rand = [cell.tre(cell.model(perm[:j])) for j in ROBOT_COUNTS]
    return {"planner": {"tre": [tre[j] for j in ROBOT_COUNTS]}, "random": {"tre": rand},
            "all_tre": cell.tre(cell.model(cell.poses)), "seconds": time.perf_counter() - t0}


def robot_report(runs: list[dict]) -> list[str]:
    mine = np.array([r["planner"]["tre"] for r in runs])
    rand = np.array([r["random"]["tre"] for r in runs])
    diff = mine - rand
    se = diff.std(axis=0, ddof=1) / np.sqrt(len(runs))
    lines = [f"### Robot cell, by pose: mean over {len(runs)} seeds of the median target TRE (mm)",
             "", f"{ROBOT_POSES} poses of {ROBOT_PER_POSE} reflectors, 40 targets, one measurement "
             f"each, sigma unknown, groups given; {ROBOT_START} random poses first, then "
             f"{ROBOT_BATCH} poses a batch. Every pose measured: "
             f"{np.mean([r['all_tre'] for r in runs]):.4f} mm.", "",
             "| poses | fiducials | planner (by pose) | random poses | planner - random (± SE) |",
             "|---|---|---|---|---|"]
    for i, j in enumerate(ROBOT_COUNTS):
        lines.append(f"| {j} | {j * ROBOT_PER_POSE} | {mine[:, i].mean():.4f} | "
                     f"{rand[:, i].mean():.4f} | {diff[:, i].mean():+.4f} ± {se[i]:.4f} |")
    above = [j for j, v in zip(ROBOT_COUNTS[1:], diff[:, 1:].mean(axis=0)) if v >= 0]
    lines += ["", f"- pose counts after the start where the planner's mean is not below "
              f"random's: {', '.join(map(str, above)) or 'none'}"]
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", default="RA,A")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--first-seed", type=int, default=0, help="seeds first-seed .. + seeds - 1")
    ap.add_argument("--json", default=None)
    ap.add_argument("--load", default=None,
                    help="comma-separated --json files of earlier runs: report them together")
    args = ap.parse_args(argv)
    config = PlanConfig()
    results: dict = {}
    print(f"Model: build_model defaults, sigma unknown, single measurements. Rules: within "
          f"{config.within}, min_gain_fraction {config.min_gain_fraction}; batches of {BATCH}.\n")
    if args.load:
        for path in args.load.split(","):
            with open(path) as f:
                results.update(json.load(f))
    else:
        for name in args.cells.split(","):
            results[name] = []
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                if name == "robot":
                    r = run_robot(seed, config)
                    print(f"robot seed {seed}: {r['seconds']:.0f} s", file=sys.stderr)
                    results[name].append(r)
                    if args.json:
                        with open(args.json, "w") as f:
                            json.dump(results, f, indent=1, default=float)
                    continue
                r = run_cell(name, seed, config)
                print(f"{name} seed {seed}: {r['seconds']:.0f} s, stop "
                      f"{r['planner']['stop']['count']}", file=sys.stderr)
                results[name].append(r)
                if args.json:
                    with open(args.json, "w") as f:
                        json.dump(results, f, indent=1, default=float)
    for name, runs in results.items():
        print("\n".join(robot_report(runs) if name == "robot" else report(name, runs)) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
