"""The barycentric transforms of a triangulation (``core/interpolation.barycentric_transforms``,
vectorised) against scipy's ``Delaunay.transform`` (LAPACK calls per simplex), alternating, and
what a cross-validation fold's hull test costs with each (``HullTest``: triangulation and
transforms of the kept fiducials).

    source scripts/env.sh && python benchmarks/bench_transforms.py [--sizes 1000,4500,9000]

Prints, per cell (3D, the grid of ``bench_node.py --during-rebuild`` with its small offsets, and
uniform random points; 2D random), min / median ms over the repeats. No ROS.
"""

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # as the node runs (rbc_registration.runtime)

import numpy as np  # noqa: E402
from scipy.spatial import Delaunay  # noqa: E402

from rbc_registration.core import interpolation  # noqa: E402


def cells(j: int) -> dict:
    rng = np.random.default_rng(0)
    side = int(np.ceil(j ** (1 / 3)))
    grid = np.array([[x, y, z] for x in range(side) for y in range(side)
                     for z in range(side)][:j], dtype=np.float64) * 0.05
    return {"3D grid": grid + 1e-4 * np.sin(grid * 3.0) + rng.normal(0, 1e-5, grid.shape),
            "3D random": rng.uniform(0, 1, (j, 3)), "2D random": rng.uniform(0, 1, (j, 2))}


def ms(values: list) -> str:
    return f"{min(values) * 1e3:.1f} / {np.median(values) * 1e3:.1f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="1000,4500,9000")
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args()
    print("| cell | J | simplices | transforms: scipy [ms] | vectorised [ms] | "
          "HullTest with scipy's [ms] | HullTest [ms] |")
    print("|---|---|---|---|---|---|---|")
    ours = interpolation._Triangulation
    for j in (int(v) for v in args.sizes.split(",")):
        for name, pts in cells(j).items():
            local = pts - pts.mean(axis=0)
            t: dict = {k: [] for k in ("scipy", "ours", "hull scipy", "hull ours")}
            for _ in range(args.repeat):               # alternating the variants
                tri = Delaunay(local, qhull_options="QJ")
                start = time.perf_counter()
                _ = tri.transform
                t["scipy"].append(time.perf_counter() - start)
                start = time.perf_counter()
                interpolation.barycentric_transforms(tri.points, tri.simplices)
                t["ours"].append(time.perf_counter() - start)
                for key, cls in (("hull scipy", Delaunay), ("hull ours", ours)):
                    interpolation._Triangulation = cls
                    try:
                        start = time.perf_counter()
                        interpolation.HullTest(pts)
                        t[key].append(time.perf_counter() - start)
                    finally:
                        interpolation._Triangulation = ours
            print(f"| {name} | {j} | {len(tri.simplices)} | {ms(t['scipy'])} | {ms(t['ours'])} | "
                  f"{ms(t['hull scipy'])} | {ms(t['hull ours'])} |", flush=True)


if __name__ == "__main__":
    main()
