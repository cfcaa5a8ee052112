"""Write the example cells of the README (``examples/cell3d/`` and ``examples/plate2d/``, mm).

Both come from the project's synthetic cells
(:func:`rbc_registration.core.synthetic.cells.make_cell`,
seed 0), cut down to a size read at a glance:

- ``cell3d``: the A-like 3D cell (3 m x 3 m x 1.8 m, a bias of sigma_L0 ~ 2.5 mm), every
  measured point 3 times. Measured fiducials: the grid nodes of even index sum (63 of 125);
  candidates: the other 62 nodes (working frame, their first measurement); targets: the 16
  targets with their truth (``dx,dy,dz``), so ``register`` reports their TRE.
- ``plate2d``: the RA-like 2D plate (holes 25 mm apart, sigma 0.11 mm). Measured fiducials: the
  holes at even column and row (a 50 mm grid), each with all its measurements (some holes are
  measured 16 times, which gives sigma); candidates: the other fiducial holes; targets: 20 of the
  plate's targets with their truth.

Coordinates are rounded to 1e-9 mm and computed with one BLAS thread, so the files come out the
same byte for byte on every run (test/test_examples.py checks the committed ones).

Usage: ``python examples/make_examples.py [--out examples]`` (the committed files are its output).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from rbc_registration.runtime import default_one_blas_thread

default_one_blas_thread()   # before numpy loads: the same sums whatever the machine's cores

import numpy as np  # noqa: E402

from rbc_registration.core.synthetic.cells import make_cell  # noqa: E402
from rbc_registration.io.csv_io import write_fiducials, write_targets  # noqa: E402

HERE = Path(__file__).resolve().parent
DECIMALS = 9   # 1e-9 mm


def _r(values):
    return np.round(np.asarray(values, dtype=np.float64), DECIMALS)


def write_cell(directory: Path, cell, measured: np.ndarray, targets: np.ndarray) -> None:
    """``fiducials.csv`` (the ``measured`` fiducials, all their rows), ``candidates.csv`` (the
    other fiducials' first measurement) and ``targets.csv`` (``targets``, with truth)."""
    directory.mkdir(parents=True, exist_ok=True)
    ids = np.array(cell.fiducial_ids)
    rest = np.setdiff1d(np.arange(len(ids)), measured)
    write_fiducials(directory / "fiducials.csv", ids[measured],
                    [_r(cell.fiducial_measurements[k]) for k in measured],
                    [_r(cell.fiducial_truth[k][None]) for k in measured])
    write_targets(directory / "candidates.csv", [f"C{ids[k][1:]}" for k in rest],
                  _r([cell.fiducial_measurements[k][0] for k in rest]))
    write_targets(directory / "targets.csv", np.array(cell.target_ids)[targets],
                  _r(cell.target_means[targets]), _r(cell.target_truth[targets]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=HERE, help="directory (default: examples/)")
    out = parser.parse_args(argv).out

    cell = make_cell("A", seed=0, repeats=3)
    node = np.arange(len(cell.fiducial_ids))
    grid_index = np.stack(np.unravel_index(node, (5, 5, 5)), axis=1)   # make_cell's ij order
    write_cell(out / "cell3d", cell, node[grid_index.sum(axis=1) % 2 == 0],
               np.arange(len(cell.target_ids)))

    plate = make_cell("RA", seed=0)
    steps = np.rint(plate.fiducial_truth / 25.0).astype(int)
    write_cell(out / "plate2d", plate, np.flatnonzero((steps % 2 == 0).all(axis=1)),
               np.arange(0, len(plate.target_ids), 4))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
