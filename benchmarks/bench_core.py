"""Benchmarks of the core math (run: `.venv/bin/python benchmarks/bench_core.py`).

- restoration: the paper's two Gauss-Newton steps at J = 125 (3D), 277 (2D), 1000 (3D):
  ``iterative`` as shipped (solver auto: matrix-free CG on the normal equations), the same steps
  with the normal matrix assembled from the pair blocks and Cholesky (``direct``), and a dense
  formulation (the J(J-1)/2 x dJ Jacobian and numpy lstsq) with the ratios; sigma_L excluded
  (timed separately), as the targets are about the solver.
- large J (``--large``): iterative for J up to 10,000 and closed-form up to 100,000.
- one target correction in process (paper and kriging).

Prints Markdown. Times are the minimum of repeated runs (wall clock, 1 BLAS thread unless
``--threads``), on whatever machine runs it; the machine should otherwise be idle.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

if "--threads" not in sys.argv:
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from rbc_registration.core.mismatch import sigma_l  # noqa: E402
from rbc_registration.core.model import ModelConfig, build_model  # noqa: E402
from rbc_registration.core.restoration import (  # noqa: E402
    dense_gauss_newton_step, gauss_newton_step, restore_rigid_body)


def cell(j: int, dim: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    y = rng.uniform(0, 3.0, (j, dim))
    x = y[:, ::-1] + 2e-3 * np.sin(2.0 * y) + rng.normal(scale=5e-5, size=y.shape)
    return x, y


def best(fn, repeat: int, budget: float = 20.0) -> float:
    times = []
    start = time.perf_counter()
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
        if time.perf_counter() - start > budget:
            break
    return min(times)


def two_steps(x, y, step):
    cur = x
    for _ in range(2):
        cur = cur - step(cur, y)
    return cur


def fmt(seconds: float) -> str:
    return f"{seconds * 1e3:.3g} ms" if seconds < 1 else f"{seconds:.3g} s"


def restoration_table(repeat: int) -> list[str]:
    rows = ["| J | d | iterative (shipped, CG) | assembled normal eq. (direct) | dense lstsq | "
            "dense / iterative | sigma_L x3 | agree (max abs diff) |",
            "|---|---|---|---|---|---|---|---|"]
    for j, d in ((125, 3), (277, 2), (1000, 3)):
        x, y = cell(j, d)
        t_it = best(lambda: restore_rigid_body(x, y, compute_sigma_l=False), repeat)
        t_dir = best(lambda: two_steps(x, y, lambda a, b: gauss_newton_step(a, b, "direct")),
                     max(3, repeat // 5))
        t_sig = best(lambda: [sigma_l(x, y) for _ in range(3)], max(3, repeat // 5))
        pairs = j * (j - 1) // 2
        dense_bytes = pairs * j * d * 8
        ref = restore_rigid_body(x, y, compute_sigma_l=False).corrections
        diff = np.abs(two_steps(x, y, lambda a, b: gauss_newton_step(a, b, "direct")) - (x - ref))
        if dense_bytes < 2e9:
            t_dense = best(lambda: two_steps(x, y, dense_gauss_newton_step), 3, budget=120)
            dense = fmt(t_dense)
            ratio = f"{t_dense / t_it:.0f}x"
            diff_dense = np.abs(two_steps(x, y, dense_gauss_newton_step) - (x - ref)).max()
            agree = f"{max(diff.max(), diff_dense):.1e}"
        else:
            dense = f"not run: the Jacobian alone is {dense_bytes / 1e9:.0f} GB"
            ratio = "n/a"
            agree = f"{diff.max():.1e} (direct)"
        rows.append(f"| {j} | {d} | {fmt(t_it)} | {fmt(t_dir)} | {dense} | {ratio} | "
                    f"{fmt(t_sig)} | {agree} |")
        print(f"  restoration J={j} done", file=sys.stderr)
    return rows


def large_table(repeat: int) -> list[str]:
    rows = ["| J | d | iterative, 2 steps (CG) | closed-form |", "|---|---|---|---|"]
    for j in (1000, 3000, 10_000, 30_000, 100_000):
        x, y = cell(j, 3)
        it = (fmt(best(lambda: restore_rigid_body(x, y, compute_sigma_l=False), 3))
              if j <= 10_000 else "-")
        cf = fmt(best(lambda: restore_rigid_body(x, y, "closed-form", compute_sigma_l=False),
                      repeat))
        rows.append(f"| {j} | 3 | {it} | {cf} |")
        print(f"  large J={j} done", file=sys.stderr)
    return rows


def correction_table(repeat: int) -> list[str]:
    rows = ["| interpolation | J | one target (model.correct) |", "|---|---|---|"]
    for method in ("paper", "kriging"):
        for j, d in ((125, 3), (277, 2)):
            x, y = cell(j, d)
            model = build_model(x, y, ModelConfig(dimension=d, interpolation=method, sigma=1e-4))
            t = x.mean(axis=0, keepdims=True)
            rows.append(f"| {method} | {j} ({d}D) | "
                        f"{best(lambda: model.correct(t), repeat) * 1e6:.0f} µs |")
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeat", type=int, default=30)
    p.add_argument("--large", action="store_true", help="also J up to 10,000 / 100,000")
    p.add_argument("--threads", action="store_true", help="keep the BLAS thread default")
    args = p.parse_args()
    print(f"BLAS threads: {os.environ.get('OPENBLAS_NUM_THREADS', 'default')}, "
          f"cores: {os.cpu_count()}\n")
    print("### Restoration (2 steps, sigma_L excluded)\n")
    print("\n".join(restoration_table(args.repeat)))
    if args.large:
        print("\n### Large J\n")
        print("\n".join(large_table(args.repeat)))
    print("\n### One target correction, in process\n")
    print("\n".join(correction_table(args.repeat * 10)))


if __name__ == "__main__":
    main()
