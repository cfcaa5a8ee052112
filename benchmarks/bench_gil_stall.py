"""How long a model rebuild keeps other Python threads waiting (the GIL): builds a ``kriging``
model of J fiducials (3D grid, cv decision) in a thread while the main thread sleeps 1 ms in a
loop and records the gaps between its wake-ups, as the node's executor would see them.

    source scripts/env.sh && python benchmarks/bench_gil_stall.py [--fiducials 5000] [--runs 2]

Prints, per run, the build time and the longest gap, the gaps over 20 and 100 ms and the 99th
percentile. Compare trees with ``PYTHONPATH=<tree>``, alternating. No ROS.
"""

import argparse
import os
import threading
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # as the node runs (rbc_registration.runtime)

import numpy as np  # noqa: E402

import rbc_registration  # noqa: E402
from rbc_registration.core.config import ModelConfig  # noqa: E402
from rbc_registration.core.model import build_model  # noqa: E402


def cell(j: int) -> tuple[np.ndarray, np.ndarray]:
    """The grid cell of ``bench_node.py --during-rebuild``: 0.05 m spacing, a smooth bias."""
    side = int(np.ceil(j ** (1 / 3)))
    grid = np.array([[x, y, z] for x in range(side) for y in range(side)
                     for z in range(side)][:j], dtype=np.float64) * 0.05
    rng = np.random.default_rng(0)
    return grid + 1e-4 * np.sin(grid * 3.0) + rng.normal(0, 1e-5, grid.shape), grid


def run(j: int) -> str:
    working, destination = cell(j)
    config = ModelConfig(dimension=3, interpolation="kriging", sigma=1e-5)
    done, out, gaps = threading.Event(), {}, []

    def build() -> None:
        t0 = time.perf_counter()
        out["method"] = build_model(working, destination, config).decision.method
        out["seconds"] = time.perf_counter() - t0
        done.set()

    thread = threading.Thread(target=build)
    last = time.perf_counter()
    thread.start()
    while not done.is_set():
        time.sleep(0.001)
        now = time.perf_counter()
        gaps.append(now - last)
        last = now
    thread.join()
    g = np.array(gaps) * 1e3
    return (f"J = {j}: build {out['seconds']:.2f} s ({out['method']}); longest gap {g.max():.0f} "
            f"ms, gaps > 20 ms: {(g > 20).sum()}, > 100 ms: {(g > 100).sum()}, p99 "
            f"{np.percentile(g, 99):.1f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fiducials", type=int, default=5000)
    parser.add_argument("--runs", type=int, default=2)
    args = parser.parse_args()
    print(f"tree: {os.path.dirname(os.path.dirname(rbc_registration.__file__))}")
    for _ in range(args.runs):
        print(run(args.fiducials), flush=True)


if __name__ == "__main__":
    main()
