"""Benchmarks of the kriging model build and of the cross-validated decision (issue 9).

- kriging model build: ``build_model(interpolation="kriging", decision="off")`` (restoration,
  both registrations, the kriging fit and its Cholesky factor, the uncorrected registration's
  leave-one-out), cold and warm-started from the previous model's hyper-parameters (the model of
  the same cell before its last 10 % of fiducials arrived, as in the node), at
  J = 277 (2D, the RA-like cell), 1000 and 5000 (3D);
- the whole decision: ``build_model`` with the defaults (decision ``cv``: every candidate
  cross-validated, the kriging fit included) at J = 125 (3D, A-like), 277 (2D) and 1000 (3D);
- one target with the default model: ``model.answer`` (the chosen method only) and
  ``model.correct`` (the configured and the chosen interpolation).

Times are wall clock with 1 BLAS thread: min and median of the repeats, the compared variants
alternated. Prints Markdown.

Run: ``.venv/bin/python benchmarks/bench_decision.py [--quick | --one-target]``
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

from bench_core import timings  # noqa: E402
from rbc_registration.core.model import ModelConfig, build_model  # noqa: E402
from rbc_registration.core.synthetic.cells import make_cell  # noqa: E402


def volume_cell(j: int, seed: int = 0):
    """J fiducials in a 3 m x 3 m x 1.8 m volume (mm): smooth bias of ~1 mm, 0.06 mm noise."""
    rng = np.random.default_rng(seed)
    y = rng.uniform(0, 1, (j, 3)) * [3000.0, 3000.0, 1800.0]
    rot = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    freq = rng.normal(size=(6, 3)) / 2000.0
    bias = np.sin(y @ freq.T + rng.uniform(0, 6, 6)) @ rng.normal(size=(6, 3)) * 0.5
    noise = rng.normal(scale=0.06 / np.sqrt(3), size=y.shape)
    return (y - 500.0) @ rot + bias + noise, y


def ra_cell(seed: int = 0):
    cell = make_cell("RA", seed)
    return np.array([m[0] for m in cell.fiducial_measurements]), cell.fiducial_truth


def fmt(times: list[float]) -> str:
    def one(s: float) -> str:
        return f"{s * 1e3:.3g} ms" if s < 1 else f"{s:.3g} s"
    return f"{one(min(times))} / {one(statistics.median(times))} ({len(times)})"


def alternate(variants: dict, repeat: int, budget: float) -> dict[str, list[float]]:
    """Run the variants in turn, ``repeat`` rounds (within ``budget`` seconds in all)."""
    out: dict[str, list[float]] = {k: [] for k in variants}
    start = time.perf_counter()
    for _ in range(repeat):
        for name, fn in variants.items():
            out[name] += timings(fn, 1, budget)
        if time.perf_counter() - start > budget:
            break
    return out


def kriging_rows(sizes, repeat: int, budget: float) -> list[str]:
    rows = ["| J | d | kriging model build, cold | warm start | target | decision (cv) of the "
            "same cell |", "|---|---|---|---|---|---|"]
    targets = {277: "0.5 s", 1000: "5 s", 5000: "10 s"}
    for j, d in sizes:
        x, y = ra_cell(0) if d == 2 else volume_cell(j)
        off = ModelConfig(dimension=d, interpolation="kriging", decision="off")
        keep = (9 * len(x)) // 10            # the node's previous model: 10 % fewer fiducials
        prev = build_model(x[:keep], y[:keep], off).kriging_hyperparameters
        variants = {
            "cold": lambda: build_model(x, y, off),
            "warm": lambda: build_model(x, y, off, kriging_warm_start=prev)}
        if j <= 1000:
            variants["cv"] = lambda: build_model(x, y, ModelConfig(dimension=d))
        res = alternate(variants, repeat if j < 5000 else max(2, repeat // 3), budget)
        cv = fmt(res["cv"]) if "cv" in res else "not run"
        rows.append(f"| {j} | {d} | {fmt(res['cold'])} | {fmt(res['warm'])} | "
                    f"≤ {targets.get(j, '-')} | {cv} |")
    return rows


def decision_rows(repeat: int, budget: float, build: bool = True) -> list[str]:
    """The decision table; ``build=False``: the one-target columns only (one build per cell)."""
    rows = ["| cell | J | d | folds | whole build with the decision (cv) | decided | "
            "one target: model.answer | model.correct |", "|---|---|---|---|---|---|---|---|"]
    a = make_cell("A", 0)
    cells = [("A-like", np.array([m[0] for m in a.fiducial_measurements]), a.fiducial_truth, 3),
             ("RA-like", *ra_cell(0), 2), ("volume", *volume_cell(1000), 3)]
    for name, x, y, d in cells:
        cfg = ModelConfig(dimension=d)
        res = timings(lambda: build_model(x, y, cfg), repeat, budget) if build else None
        model = build_model(x, y, cfg)
        one = x[:1] + 1.0
        model.correct(one)
        t_answer = min(timings(lambda: model.answer(one), 2000, 5.0))
        t_correct = min(timings(lambda: model.correct(one), 2000, 5.0))
        rows.append(f"| {name} | {len(x)} | {d} | {model.decision.folds.describe()} | "
                    f"{fmt(res) if build else '-'} | {model.decision.method} | "
                    f"{t_answer * 1e6:.0f} µs | {t_correct * 1e6:.0f} µs |")
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats, no J = 5000")
    parser.add_argument("--one-target", action="store_true",
                        help="only model.answer / model.correct of one target, no build timings "
                             "(e.g. to compare trees: PYTHONPATH=<tree>)")
    args = parser.parse_args(argv)
    if args.one_target:
        print("\n".join(decision_rows(1, 60.0, build=False)))
        return 0
    repeat = 3 if args.quick else 7
    sizes = [(277, 2), (1000, 3)] + ([] if args.quick else [(5000, 3)])
    print(f"BLAS threads: {os.environ.get('OPENBLAS_NUM_THREADS')}, cores: {os.cpu_count()}; "
          f"times: min / median (repeats)\n")
    print("### Kriging model build\n")
    print("\n".join(kriging_rows(sizes, repeat, 120.0)))
    print("\n### The decision\n")
    print("\n".join(decision_rows(repeat, 60.0)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
