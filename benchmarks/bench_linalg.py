"""The GIL-free blocked inverse (``core/blocked_linalg.inverse_from_cholesky``) by its block size,
against LAPACK ``dpotri`` (which holds the GIL), alternating, one BLAS thread.

    source scripts/env.sh && python benchmarks/bench_linalg.py [--sizes 300,1000,2000]

Prints, per matrix size n and block size, min / median ms over the repeats, and the largest
relative difference from the default block's inverse. No ROS.
"""

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # as the node runs (rbc_registration.runtime)

import numpy as np  # noqa: E402
from scipy.linalg import lapack  # noqa: E402
from scipy.spatial.distance import cdist  # noqa: E402

from rbc_registration.core import blocked_linalg  # noqa: E402

BLOCKS = (512, 256, 128, 64)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="300,1000,2000")
    parser.add_argument("--repeat", type=int, default=15)
    args = parser.parse_args()
    default = blocked_linalg.INVERSE_BLOCK
    print(f"default INVERSE_BLOCK = {default}\n")
    print("| n | " + " | ".join(f"block {b} [ms]" for b in BLOCKS) + " | dpotri [ms] |")
    print("|---|" + "---|" * (len(BLOCKS) + 1))
    for n in (int(v) for v in args.sizes.split(",")):
        x = np.random.default_rng(0).uniform(0.0, 1.0, (n, 3))
        factor = np.linalg.cholesky(np.exp(-cdist(x, x) / 0.3) + 1e-3 * np.eye(n))
        reference = blocked_linalg.inverse_from_cholesky(factor)
        times: dict = {b: [] for b in BLOCKS + ("dpotri",)}
        diff = {}
        for _ in range(args.repeat):                   # alternating the variants
            for b in BLOCKS:
                blocked_linalg.INVERSE_BLOCK = b
                t = time.perf_counter()
                got = blocked_linalg.inverse_from_cholesky(factor)
                times[b].append(time.perf_counter() - t)
                diff[b] = float(np.abs(got - reference).max() / np.abs(reference).max())
            t = time.perf_counter()
            lapack.dpotri(factor, lower=1)
            times["dpotri"].append(time.perf_counter() - t)
        blocked_linalg.INVERSE_BLOCK = default
        cells = [f"{min(times[b]) * 1e3:.1f} / {np.median(times[b]) * 1e3:.1f} "
                 f"(diff {diff[b]:.0e})" for b in BLOCKS]
        cells.append(f"{min(times['dpotri']) * 1e3:.1f} / {np.median(times['dpotri']) * 1e3:.1f}")
        print(f"| {n} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
