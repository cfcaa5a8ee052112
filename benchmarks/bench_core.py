"""Benchmarks of the core math (run: `.venv/bin/python benchmarks/bench_core.py`).

- restoration: the paper's two Gauss-Newton steps at J = 125 (3D), 277 (2D), 1000 (3D):
  ``iterative`` as shipped (solver auto: matrix-free CG on the normal equations), the same steps
  with the normal matrix assembled from the pair blocks and Cholesky (``direct``), and a dense
  formulation (the J(J-1)/2 x dJ Jacobian and numpy lstsq) with the ratios; sigma_L excluded
  (timed separately), as the targets are about the solver.
- model rebuild: ``build_model`` with its defaults (3D, iterative, paper, the ``cv`` decision,
  which cross-validates every candidate) at J = 1,000 to 10,000,
  against a floor in the same run (one O(J) rigid fit of the same fiducials), and what it is made
  of (sigma_L0, the restoration, the interpolator's Delaunay triangulation and k-d tree).
- target corrections, batched: ``RbcModel.correct`` (hull test, interpolation, both rigid maps) of
  K = 10,000 targets per call against a floor in the same run, ``cKDTree.query(targets, k=8)`` on
  the same fiducials (batched, same K), alternating, min and median per target and their ratios
  (wall clock and thread CPU time); the first two calls after a build are shown apart (2D: the
  grid cells are prepared once 8 targets fell in them, so calls 1-7 take the staged path).
- ``--fresh``: 2D ``correct`` of 10,000 new random targets in every call, batch by batch;
  ``--calls``: of the same targets call after call (CPU time per call, then the ratio); compare
  trees with ``PYTHONPATH=<tree>``, alternating.
- large J (``--large``): iterative for J up to 10,000 and closed-form up to 100,000.
- one target correction in process (paper and kriging); ``--one-target``: only this table.
- ``--modes``: only a paper rebuild (``build_model``, 3D) per decision mode at J = 5,000 and
  10,000, wall clock and the CPU time of all threads (``cv`` cross-validates the kriging
  candidate in a thread of its own).

Prints Markdown. Times are wall clock (1 BLAS thread unless ``--threads``), on whatever machine
runs it; the machine should otherwise be idle, and ratios against a floor measured in the same
run, alternating, are the figures to compare between machines.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

if "--threads" not in sys.argv:
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import rbc_registration  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402

from rbc_registration.core.interpolation.paper import PaperInterpolator  # noqa: E402
from rbc_registration.core.rigid.mismatch import sigma_l  # noqa: E402
from rbc_registration.core.model import ModelConfig, build_model  # noqa: E402
from rbc_registration.core.rigid.registration import rigid_fit  # noqa: E402
from rbc_registration.core.rigid.gauss_newton import (  # noqa: E402
    dense_gauss_newton_step, gauss_newton_step)
from rbc_registration.core.rigid.restoration import restore_rigid_body  # noqa: E402


def turned(y: np.ndarray) -> np.ndarray:
    """``y`` with its axes reversed and the new last one negated: a rotation. Reversing alone
    is a reflection, which ``build_model`` refuses as a mirrored frame."""
    x = y[:, ::-1].copy()
    x[:, -1] *= -1.0
    return x


def cell(j: int, dim: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    y = rng.uniform(0, 3.0, (j, dim))
    x = turned(y) + 2e-3 * np.sin(2.0 * y) + rng.normal(scale=5e-5, size=y.shape)
    return x, y


def timings(fn, repeat: int, budget: float = 20.0) -> list[float]:
    """Wall-clock times of up to ``repeat`` calls of ``fn`` (stopping after ``budget`` s)."""
    times = []
    start = time.perf_counter()
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
        if time.perf_counter() - start > budget:
            break
    return times


def best(fn, repeat: int, budget: float = 20.0) -> float:
    return min(timings(fn, repeat, budget))


def min_med(values, show=None) -> str:
    """``min / median`` of times in seconds, each shown by ``show`` (default :func:`fmt`)."""
    v = np.asarray(values)
    show = show or fmt
    return f"{show(v.min())} / {show(float(np.median(v)))}"


def ratios(a, b) -> str:
    """``min(a) / min(b)`` and ``median(a) / median(b)``."""
    return f"{np.min(a) / np.min(b):.2f} / {np.median(a) / np.median(b):.2f}"


def seconds(fn) -> float:
    """Wall-clock time of one call."""
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def alternate(fns: dict, repeat: int, budget: float = 60.0) -> tuple[dict, dict]:
    """Run the callables in turn, ``repeat`` rounds (fewer when over ``budget`` s). Returns the
    wall-clock and the thread CPU times of each, in seconds (CPU time does not count the time the
    thread waited for a core, so it is steadier on a shared machine)."""
    wall = {name: [] for name in fns}
    cpu = {name: [] for name in fns}
    start = time.perf_counter()
    for _ in range(repeat):
        for name, fn in fns.items():
            c, t = time.thread_time(), time.perf_counter()
            fn()
            wall[name].append(time.perf_counter() - t)
            cpu[name].append(time.thread_time() - c)
        if time.perf_counter() - start > budget:
            break
    return wall, cpu


def grid_cell(dim: int, seed: int = 0):
    """A-like (5 x 5 x 5 holes over 3 m x 3 m x 1.8 m) or RA-like (17 x 21 holes, 25 mm) cell,
    destination = holes, working = rotated copy + smooth bias + noise (metres)."""
    rng = np.random.default_rng(seed)
    if dim == 3:
        axes = [np.linspace(0, 3, 5), np.linspace(0, 3, 5), np.linspace(0, 1.8, 5)]
    else:
        axes = [np.arange(17) * 0.025, np.arange(21) * 0.025]
    y = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, dim)
    x = turned(y) + 2e-4 * np.sin(5.0 * y) + rng.normal(scale=5e-6, size=y.shape)
    return x, y


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


def rebuild_table(repeat: int) -> list[str]:
    rows = ["| J | build_model (paper, 3D): min / median | CPU time: min / median | floor: one "
            "rigid fit, min | sigma_L0 | restoration | interpolator (Delaunay + k-d tree) | "
            "sigma_L1 and sigma_L2, on first access |", "|---|---|---|---|---|---|---|---|"]
    for j in (1000, 5000, 10_000):
        x, y = cell(j, 3)
        wall, cpu = alternate({"build": lambda: build_model(x, y),
                               "floor": lambda: rigid_fit(x, y)}, repeat)
        res = restore_rigid_body(x, y)
        parts, _ = alternate({"sigma0": lambda: sigma_l(x, y),
                              "restore": lambda: restore_rigid_body(x, y),
                              "interp": lambda: PaperInterpolator(x, res.corrections)},
                             max(3, repeat // 2))
        models = [build_model(x, y) for _ in range(max(3, repeat // 2))]
        rest = [seconds(lambda: m.sigma_l) for m in models]
        cols = [str(j), min_med(wall["build"]), min_med(cpu["build"]), fmt(min(wall["floor"])),
                fmt(min(parts["sigma0"])), fmt(min(parts["restore"])), fmt(min(parts["interp"])),
                fmt(min(rest))]
        rows.append("| " + " | ".join(cols) + " |")
        print(f"  rebuild J={j} done", file=sys.stderr)
    return rows


def batch_table(repeat: int, k: int = 10_000) -> list[str]:
    rows = ["| cell | J | d | correct: min / median | floor (k = 8 query): min / median | "
            "ratio, wall: min / median | ratio, CPU time: min / median | 1st call / 2nd call |",
            "|---|---|---|---|---|---|---|---|"]
    cases = [("grid A-like", *grid_cell(3)), ("random", *cell(125, 3)),
             ("random", *cell(1000, 3)), ("grid RA-like", *grid_cell(2)),
             ("random", *cell(277, 2)), ("random", *cell(1000, 2))]
    for name, x, y in cases:
        d = x.shape[1]
        model = build_model(x, y, ModelConfig(dimension=d, sigma=1e-4))
        rng = np.random.default_rng(1)
        lo, hi = x.min(axis=0), x.max(axis=0)
        targets = lo + (hi - lo) * rng.uniform(size=(k, d))
        tree = cKDTree(model.interpolator.points)
        # 2D: calls 1-7 take the staged path, the 8th prepares the grid cells (PREPARE_AFTER)
        # and uses them.
        cold = [seconds(lambda: model.correct(targets)) for _ in range(2)]
        wall, cpu = alternate({"correct": lambda: model.correct(targets),
                               "floor": lambda: tree.query(targets, k=8)}, repeat)
        def us(v: float) -> str:                      # per target
            return f"{v * 1e6 / k:.2f} µs"

        cols = [name, str(len(x)), str(d), min_med(wall["correct"], us),
                min_med(wall["floor"], us), ratios(wall["correct"], wall["floor"]),
                ratios(cpu["correct"], cpu["floor"]), f"{fmt(cold[0])} / {fmt(cold[1])}"]
        rows.append("| " + " | ".join(cols) + " |")
        print(f"  batch {name} J={len(x)} {d}D done", file=sys.stderr)
    return rows


def fresh_table(batches: int = 12, k: int = 10_000) -> list[str]:
    """2D ``correct_targets`` of new random targets in every call (one model kept): most take
    the staged path of the sector rule; a grid cell is prepared once ``PREPARE_AFTER`` targets
    fell in it, so few cells are prepared within a dozen batches of 10,000."""
    shown = [b for b in (1, 2, 3, 4, 6, 8, 12, 16, 24) if b <= batches]
    rows = ["| cell | J | " + " | ".join(f"batch {b}" for b in shown) + " |",
            "|---|---|" + "---|" * len(shown)]
    for name, x, y in [("grid RA-like", *grid_cell(2)), ("random", *cell(277, 2)),
                       ("random", *cell(1000, 2))]:
        model = build_model(x, y, ModelConfig(dimension=2, sigma=1e-4))
        tree = cKDTree(model.interpolator.points)
        rng = np.random.default_rng(2)
        lo, hi = x.min(axis=0), x.max(axis=0)
        got = {}
        for b in range(1, max(shown) + 1):
            targets = lo + (hi - lo) * rng.uniform(size=(k, 2))
            t = seconds(lambda: model.correct(targets))
            floor = seconds(lambda: tree.query(targets, k=8))
            got[b] = f"{t * 1e6 / k:.1f} µs ({t / floor:.1f}x)"
        rows.append(f"| {name} | {len(x)} | " + " | ".join(got[b] for b in shown) + " |")
        print(f"  fresh batches {name} J={len(x)} done", file=sys.stderr)
    return rows


def modes_table(repeat: int = 2) -> list[str]:
    rows = ["| J | decision | build_model (interpolation paper, 3D): min / max | CPU time of all "
            "threads: min |", "|---|---|---|---|"]
    for j in (5000, 10_000):
        x, y = cell(j, 3)
        for mode in ("off", "on", "rho", "cv"):
            config = ModelConfig(decision=mode, sigma=1e-4)
            wall, cpu = [], []
            for _ in range(repeat):
                c, t = time.process_time(), time.perf_counter()
                build_model(x, y, config)
                wall.append(time.perf_counter() - t)
                cpu.append(time.process_time() - c)
            rows.append(f"| {j} | {mode} | {fmt(min(wall))} / {fmt(max(wall))} | "
                        f"{fmt(min(cpu))} |")
            print(f"  modes J={j} {mode} done", file=sys.stderr)
    return rows


def calls_table(calls: int = 10, k: int = 10_000) -> list[str]:
    """2D ``correct_targets`` of the same targets call after call (a new model per cell): CPU
    time per target of each of the first calls (the grid cells are prepared on the
    ``PREPARE_AFTER``-th), then the ratio to the k = 8 query over 20 more calls."""
    rows = ["| cell | J | " + " | ".join(f"call {c}" for c in range(1, calls + 1))
            + " | then: ratio to the k = 8 query, min / median |",
            "|---|---|" + "---|" * (calls + 1)]
    for name, x, y in [("grid RA-like", *grid_cell(2)), ("random", *cell(277, 2)),
                       ("random", *cell(1000, 2))]:
        model = build_model(x, y, ModelConfig(dimension=2, sigma=1e-4))
        tree = cKDTree(model.interpolator.points)
        lo, hi = x.min(axis=0), x.max(axis=0)
        targets = lo + (hi - lo) * np.random.default_rng(1).uniform(size=(k, 2))

        def cpu(fn) -> float:
            t = time.thread_time()
            fn()
            return time.thread_time() - t

        first = [cpu(lambda: model.correct(targets)) for _ in range(calls)]
        then = [cpu(lambda: model.correct(targets)) / cpu(lambda: tree.query(targets, k=8))
                for _ in range(20)]
        rows.append(f"| {name} | {len(x)} | " + " | ".join(f"{t * 1e6 / k:.1f} µs" for t in first)
                    + f" | {min(then):.2f} / {float(np.median(then)):.2f} |")
        print(f"  calls {name} J={len(x)} done", file=sys.stderr)
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
    p.add_argument("--fresh", action="store_true",
                   help="only the 2D batches of new targets in every call (per target, ratio "
                        "to the k = 8 query)")
    p.add_argument("--calls", action="store_true",
                   help="only the 2D calls of the same targets, one after another (per target, "
                        "then the ratio to the k = 8 query)")
    p.add_argument("--one-target", action="store_true",
                   help="only the one-target table (e.g. to compare trees: PYTHONPATH=<tree>)")
    p.add_argument("--modes", action="store_true",
                   help="only the paper rebuild per decision mode at J = 5,000 and 10,000")
    args = p.parse_args()
    print(f"BLAS threads: {os.environ.get('OPENBLAS_NUM_THREADS', 'default')}, "
          f"cores: {os.cpu_count()}\n")
    if args.fresh:
        print("### Target corrections, 2D, new targets in every call (K = 10,000)\n")
        print("\n".join(fresh_table()))
        return
    if args.modes:
        print("### Model rebuild by decision mode (paper, 3D)\n")
        print("\n".join(modes_table()))
        return
    if args.calls:
        print("### Target corrections, 2D, the same targets call after call (K = 10,000)\n")
        print("\n".join(calls_table()))
        return
    if args.one_target:
        tree = os.path.dirname(os.path.dirname(rbc_registration.__file__))
        print(f"### One target correction, in process ({tree})\n")
        print("\n".join(correction_table(args.repeat * 10)))
        return
    print("### Restoration (2 steps, sigma_L excluded)\n")
    print("\n".join(restoration_table(args.repeat)))
    print("\n### Model rebuild (build_model defaults: 3D, iterative, paper)\n")
    print("\n".join(rebuild_table(max(5, args.repeat // 3))))
    print("\n### Target corrections, batched (K = 10,000 per call)\n")
    print("\n".join(batch_table(args.repeat)))
    if args.large:
        print("\n### Large J\n")
        print("\n".join(large_table(args.repeat)))
    print("\n### One target correction, in process\n")
    print("\n".join(correction_table(args.repeat * 10)))


if __name__ == "__main__":
    main()
