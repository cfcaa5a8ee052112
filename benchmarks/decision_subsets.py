"""Which correction the ``cv`` decision picks on few fiducials, and what it costs at the targets.

Per cell (``RA``, ``A`` of :mod:`rbc_registration.core.synthetic.cells`) and seed, single
measurements (the first of every fiducial and target; sigma given: the cell's; kriging
configured, as in ``plan_cells.py``), random subsets of the fiducials (one random order per
seed, its first n for each n in ``--counts``) go through ``build_model``. For each model the
median target TRE against the truth is taken for every candidate (uncorrected, paper,
kriging), and the choice is made by

- ``preference`` (the shipped rule, :func:`~rbc_registration.core.decision.choice.decide`):
  among the corrections that beat the uncorrected registration, the first in
  ``decision.PREFERENCE`` unless another's held-out errors are significantly smaller than its
  own;
- ``smallest median``: among the same corrections, the smallest cross-validated median (the rule
  before PREFERENCE), computed here from the same decision record.

Prints, per cell, how often each rule picks each method, the mean median TRE of each rule per count,
and every set where the two rules differ. Run:
``.venv/bin/python benchmarks/decision_subsets.py [--seeds 10] [--cells RA,A]`` (~1 min).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections import Counter

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from rbc_registration.core.answers import TargetEvaluation  # noqa: E402
from rbc_registration.core.constants import CANDIDATES, UNCORRECTED  # noqa: E402
from rbc_registration.core.decision.choice import SIGNIFICANCE, Decision  # noqa: E402
from rbc_registration.core.model import ModelConfig, build_model  # noqa: E402
from rbc_registration.core.synthetic.cells import make_cell  # noqa: E402
from rbc_registration.core.validation import as_points  # noqa: E402

COUNTS = (11, 12, 13, 15, 20, 25, 30, 40, 50, 60)


def smallest_median(decision: Decision) -> str:
    """The choice by the smallest held-out median among the corrections that pass the test."""
    tested = [c for c in decision.candidates[1:] if c.available and c.p_value is not None]
    winners = [c for c in tested if c.p_value < SIGNIFICANCE / max(len(tested), 1)]
    return min(winners, key=lambda c: c.cv_median).method if winners else UNCORRECTED


def run(name: str, seed: int, counts: tuple[int, ...]) -> list[dict]:
    cell = make_cell(name, seed)
    dim, sigma = cell.spec.dimension, cell.spec.sigma
    x = np.array([m[0] for m in cell.fiducial_measurements])
    targets = as_points(np.array([m[0] for m in cell.target_measurements]), "targets", dim)
    order = np.random.default_rng(1000 + seed).permutation(len(x))
    rows = []
    for n in counts:
        idx = order[:n]
        model = build_model(x[idx], cell.fiducial_truth[idx],
                            ModelConfig(dimension=dim, interpolation="kriging", sigma=sigma))
        ev = TargetEvaluation(model, targets)
        tre = {m: float(np.median(np.linalg.norm(ev.registered(m) - cell.target_truth, axis=1)))
               for m in CANDIDATES if m == UNCORRECTED or m in model.interpolators}
        rows.append({"seed": seed, "n": n, "tre": tre,
                     "rules": {"preference": model.decision.method,
                               "smallest median": smallest_median(model.decision)}})
    return rows


def report(name: str, rows: list[dict], counts: tuple[int, ...]) -> list[str]:
    rules = ("preference", "smallest median")
    out = [f"### {name}, {len({r['seed'] for r in rows})} seeds, {len(rows)} fiducial sets", ""]
    for rule in rules:
        picks = Counter(r["rules"][rule] for r in rows)
        out.append(f"- {rule}: " + ", ".join(f"{m} {picks[m]}" for m in CANDIDATES))
    out += ["", "| rule | " + " | ".join(str(n) for n in counts) + " |",
            "|---|" + "---|" * len(counts)]
    for rule in rules:
        means = [np.mean([r["tre"][r["rules"][rule]] for r in rows if r["n"] == n]) for n in counts]
        out.append(f"| {rule} | " + " | ".join(f"{v:.4f}" for v in means) + " |")
    diff = [r for r in rows if r["rules"]["preference"] != r["rules"]["smallest median"]]
    out += ["", f"Sets where the rules differ: {len(diff)}"]
    for r in diff:
        a, b = (r["rules"][k] for k in rules)
        out.append(f"- seed {r['seed']}, {r['n']} fiducials: {a} {r['tre'][a]:.4f} mm, "
                   f"{b} {r['tre'][b]:.4f} mm")
    better = sum(r["tre"][r["rules"]["preference"]] < r["tre"][r["rules"]["smallest median"]]
                 for r in diff)
    out += [f"- preference lower at the targets in {better} of {len(diff)}", ""]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", default="RA,A")
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--counts", default=",".join(str(n) for n in COUNTS))
    args = ap.parse_args(argv)
    counts = tuple(int(n) for n in args.counts.split(","))
    for name in args.cells.split(","):
        rows = [r for seed in range(args.seeds) for r in run(name, seed, counts)]
        print("\n".join(report(name, rows, counts)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
