"""Calibration of kriging's summary conditioning above ``EXACT_MAX_FIDUCIALS`` against the exact GP.

For each cell (2D and 3D, short and long length scales, J = 1,000-5,000) the same fiducials and
hyper-parameters are conditioned exactly and by the summary
(``core/interpolation/kriging_summary.py``), and
the script prints the distribution of the ratio summary / exact of

- the posterior standard deviation at targets inside the cell's box (and 10 % beyond it),
- the held-out predictive standard deviation of the 10-fold cross-validation,
- the held-out prediction errors |prediction - value| (RMS ratio) on a smooth field plus noise,

and the share of held-out values within 1.96 held-out standard deviations (coverage, per axis).
No ROS, one BLAS thread as the node.

    source scripts/env.sh && python benchmarks/bench_kriging_summary.py            # ~5 min
    python benchmarks/bench_kriging_summary.py --cells 3d-grid-5000 --targets 500   # one cell
"""

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from rbc_registration.core import kriging, kriging_summary  # noqa: E402
from rbc_registration.core.decision.crossval import K_FOLDS, FoldScheme, fold_groups  # noqa: E402
from rbc_registration.core.interpolation.gp_fit import KrigingHyperparameters  # noqa: E402


def grid3(j):
    side = int(np.ceil(j ** (1 / 3)))
    g = np.array([[x, y, z] for x in range(side) for y in range(side)
                  for z in range(side)][:j], dtype=np.float64) * 0.05
    return g + np.random.default_rng(0).normal(0, 1e-5, g.shape)


def uniform(j, d, seed=1):
    return np.random.default_rng(seed).uniform(0.0, 1.0, (j, d))


# name: (points, length scale, noise_std / signal_std). Signal std 1 (the ratios do not depend
# on it); noise_std of one measurement (all axes), as KrigingHyperparameters holds it.
CELLS = {
    "3d-grid-5000 l=0.12 (fitted)": (lambda: grid3(5000), 0.123, 0.41),
    "3d-grid-5000 l=0.5": (lambda: grid3(5000), 0.5, 0.41),
    "3d-grid-5000 l=2": (lambda: grid3(5000), 2.0, 0.41),
    "3d-uniform-3000 l=0.1": (lambda: uniform(3000, 3), 0.1, 0.3),
    "3d-uniform-3000 l=1": (lambda: uniform(3000, 3), 1.0, 0.1),
    "2d-uniform-1000 l=0.05": (lambda: uniform(1000, 2), 0.05, 0.3),
    "2d-uniform-1500 l=0.5": (lambda: uniform(1500, 2), 0.5, 0.3),
    "2d-uniform-3000 l=0.5": (lambda: uniform(3000, 2), 0.5, 0.1),
    "2d-uniform-3000 l=2": (lambda: uniform(3000, 2), 2.0, 0.3),
    "2d-uniform-5000 l=0.02": (lambda: uniform(5000, 2), 0.02, 0.3),
    "2d-uniform-5000 l=0.3": (lambda: uniform(5000, 2), 0.3, 0.03),
}


def build(points, values, hyper, exact):
    saved = kriging.EXACT_MAX_FIDUCIALS
    kriging.EXACT_MAX_FIDUCIALS = len(points) if exact else min(saved, len(points) - 1)
    try:
        t0 = time.perf_counter()
        ip = kriging.KrigingInterpolator(points, values, hyperparameters=hyper)
        return ip, time.perf_counter() - t0
    finally:
        kriging.EXACT_MAX_FIDUCIALS = saved


def quantiles(x):
    q = np.percentile(x, [0, 5, 50, 95, 100])
    return " / ".join(f"{v:.3f}" for v in q)


def run_cell(name, targets, rng):
    make, length, noise_ratio = CELLS[name]
    x = make()
    j, d = x.shape
    hyper = KrigingHyperparameters(1.0, length, noise_ratio * np.sqrt(d), False)
    phase = rng.uniform(0, 6, d)
    values = np.sin(x / length + phase) + rng.normal(0, noise_ratio, x.shape)
    lo, hi = x.min(axis=0), x.max(axis=0)
    pad = 0.1 * (hi - lo)
    t = rng.uniform(lo - pad, hi + pad, (targets, d))
    exact, t_exact = build(x, values, hyper, True)
    approx, t_approx = build(x, values, hyper, False)
    sd_e, sd_a = exact(t).expected_error, approx(t).expected_error
    groups = fold_groups(x, FoldScheme("k-fold", K_FOLDS))
    t0 = time.perf_counter()
    ho_e = exact.held_out(groups)
    t_ho_e = time.perf_counter() - t0
    t0 = time.perf_counter()
    ho_a = approx.held_out(groups)
    t_ho_a = time.perf_counter() - t0
    std_e, std_a, err_e, err_a = (np.empty(j), np.empty(j), np.empty((j, d)), np.empty((j, d)))
    for s, (we, se), (wa, sa) in zip(groups, ho_e, ho_a):
        rest = np.setdiff1d(np.arange(j), s)
        std_e[s], std_a[s] = se, sa
        err_e[s] = we @ values[rest] - values[s]
        err_a[s] = wa @ values[rest] - values[s]
    cover_e = np.mean(np.abs(err_e) <= 1.96 * std_e[:, None])
    cover_a = np.mean(np.abs(err_a) <= 1.96 * std_a[:, None])
    rms = np.sqrt(np.mean(err_a ** 2)) / np.sqrt(np.mean(err_e ** 2))
    print(f"{name} (J = {j}, {d}D, noise/signal {noise_ratio}):\n"
          f"  target sd summary/exact (min / p5 / median / p95 / max): {quantiles(sd_a / sd_e)}"
          f"  [below 1 - 1e-9: {np.sum(sd_a < sd_e * (1 - 1e-9))}]\n"
          f"  held-out sd summary/exact:                               {quantiles(std_a / std_e)}"
          f"  [below 1 - 1e-9: {np.sum(std_a < std_e * (1 - 1e-9))}]\n"
          f"  held-out error RMS summary/exact {rms:.3f}; coverage of 1.96 sd: exact "
          f"{cover_e:.3f}, summary {cover_a:.3f}\n"
          f"  build exact {t_exact:.2f} s, summary {t_approx:.2f} s; held-out exact "
          f"{t_ho_e:.2f} s, summary {t_ho_a:.2f} s", flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cells", nargs="*", default=list(CELLS),
                        help="cell names (prefix match); default all")
    parser.add_argument("--targets", type=int, default=2000)
    args = parser.parse_args()
    rng = np.random.default_rng(7)
    print(f"EXACT_MAX_FIDUCIALS {kriging.EXACT_MAX_FIDUCIALS}, neighbours "
          f"{kriging_summary.LOCAL_NEIGHBOURS}, inducing "
          f"{kriging_summary.INDUCING_POINTS}")
    for name in CELLS:
        if any(name.startswith(c) for c in args.cells):
            run_cell(name, args.targets, rng)


if __name__ == "__main__":
    main()
