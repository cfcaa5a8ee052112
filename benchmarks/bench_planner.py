"""Speed of the measurement planner (target: rank 300 candidates at J = 100 in <= 0.5 s).

Run: ``.venv/bin/python benchmarks/bench_planner.py [--repeats 15]``.

A bias-plus-noise cell like the synthetic ones (2D: 400 x 500 mm plate; 3D: 3 x 3 x 1.8 m),
J = 100 fiducials, C = 300 candidates, the error model from a kriging model built once (its
hyper-parameter fit is timed separately: a node or CLI has the model already). Timed:
:func:`plan` with targets (K = 80) or the work volume (about 400 grid points), count 1 and 10,
isotropic and anisotropic noise, candidates one by one or in groups of 3 (a robot pose, a
rank-3 update each); and the whole :func:`plan_from_model` including the error model and its
check against the cross-validated errors (:mod:`rbc_registration.core.planning.model_check`).
The cases are run in turn, round after round, so machine load hits all alike; min and median
over the rounds. 1 BLAS thread (as the node runs). Prints Markdown.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from rbc_registration.core.planning.expected_error import ExpectedErrorModel  # noqa: E402
from rbc_registration.core.model import ModelConfig, build_model  # noqa: E402
from rbc_registration.core.planning.model_planner import error_model_from, plan_from_model  # noqa: E402
from rbc_registration.core.planning.planner import plan  # noqa: E402


def cell(dim: int, j: int, c: int, k: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    ext = np.array([400.0, 500.0]) if dim == 2 else np.array([3000.0, 3000.0, 1800.0])
    pts = rng.uniform(0, 1, (j + c + k, dim)) * ext
    bias = 0.3 * np.sin(pts @ (rng.normal(size=(dim, dim)) / ext.max() * 4))
    working = pts + bias + rng.normal(scale=0.06, size=pts.shape)
    return working[:j], pts[:j], working[j:j + c], working[j + c:]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fiducials", type=int, default=100)
    ap.add_argument("--candidates", type=int, default=300)
    ap.add_argument("--repeats", type=int, default=15)
    args = ap.parse_args(argv)
    j, c = args.fiducials, args.candidates
    cases, notes = {}, {}
    for dim in (2, 3):
        x, y, cand, targets = cell(dim, j, c, 80)
        t = time.perf_counter()
        model = build_model(x, y, ModelConfig(dimension=dim, interpolation="kriging",
                                              sigma=0.06 * np.sqrt(dim)))
        notes[dim] = time.perf_counter() - t
        em = error_model_from(model)
        aniso = ExpectedErrorModel.from_axis_std(em.signal_std, em.length_scale,
                                         np.array([0.05, 0.02, 0.03])[:dim])
        for label, e in (("isotropic", em), ("anisotropic", aniso)):
            for tg_label, tg in (("80 targets", targets), ("work volume", None)):
                for count in (1, 10):
                    key = (dim, label, tg_label, count)
                    cases[key] = (lambda e=e, tg=tg, count=count, x=x, cand=cand:
                                  plan(x, cand, e, tg, count=count))
        groups = [f"pose{k // 3}" for k in range(len(cand))]
        for count in (1, 10):
            cases[(dim, "isotropic", f"80 targets, {len(cand) // 3} groups of 3", count)] = (
                lambda em=em, x=x, cand=cand, tg=targets, count=count, groups=groups:
                plan(x, cand, em, tg, count=count, groups=groups))
        cases[(dim, "isotropic", "80 targets, plan_from_model (error model and its check "
                                 "incl.)", 1)] = (
            lambda m=model, cand=cand, tg=targets: plan_from_model(m, cand, tg))
    times = {key: [] for key in cases}
    sizes = {key: len(fn().points) for key, fn in cases.items()}      # warm-up
    for _ in range(args.repeats):
        for key, fn in cases.items():
            t = time.perf_counter()
            fn()
            times[key].append(time.perf_counter() - t)
    print(f"J = {j} fiducials, C = {c} candidates, 1 BLAS thread, {args.repeats} rounds\n")
    print("| d | noise | error taken at | points | count | min | median |")
    print("|---|---|---|---|---|---|---|")
    for key, ts in times.items():
        dim, label, tg_label, count = key
        print(f"| {dim} | {label} | {tg_label} | {sizes[key]} | {count} | "
              f"{1e3 * min(ts):.1f} ms | {1e3 * float(np.median(ts)):.1f} ms |")
    print("\nBuilding the kriging model once (hyper-parameter fit, not part of ranking): "
          + ", ".join(f"{d}D {1e3 * s:.0f} ms" for d, s in notes.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
