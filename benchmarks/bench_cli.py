"""Start-up and run time of the ``rbc-registration`` console script, as a user runs it.

- ``rbc-registration --help``: how long the parser takes (no subcommand imports).
- ``rbc-registration register FIDUCIALS.csv --targets TARGETS.csv``: the synthetic RA-like cell
  (277 fiducials, 2D, 52 of them measured 16 times; 80 targets with truth), written once.

Each run is a fresh process (wall clock, ``time.perf_counter`` around ``subprocess.run``).
Several source trees can be compared on the same files: ``--tree NAME=DIR`` runs the console
script with ``PYTHONPATH=DIR`` (a checkout's root, e.g. ``git archive main | tar -x -C DIR``);
trees are alternated run by run so that machine load hits them alike. Prints min and median.

    python benchmarks/bench_cli.py --repeats 15
    python benchmarks/bench_cli.py --tree before=/tmp/base --tree after=. --repeats 15
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def write_cell(directory: Path) -> tuple[Path, Path]:
    """FIDUCIALS.csv and TARGETS.csv of the RA-like cell (seed 0, mm)."""
    from rbc_registration.core.synthetic.cells import make_cell
    from rbc_registration.io.csv_io import write_fiducials, write_targets

    cell = make_cell("RA", seed=0)
    fiducials, targets = directory / "fiducials.csv", directory / "targets.csv"
    write_fiducials(fiducials, cell.fiducial_ids, cell.fiducial_measurements,
                    [t[None] for t in cell.fiducial_truth])
    write_targets(targets, cell.target_ids, cell.target_means, cell.target_truth)
    return fiducials, targets


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeats", type=int, default=15, help="runs per command and tree")
    p.add_argument("--tree", action="append", default=[], metavar="NAME=DIR",
                   help="a source tree to run (PYTHONPATH=DIR); default: the installed package")
    p.add_argument("--only", choices=("help", "register"), help="one command only")
    args = p.parse_args(argv)
    script = shutil.which("rbc-registration")
    if script is None:
        p.error("rbc-registration is not on PATH (source scripts/env.sh)")
    trees = [t.split("=", 1) for t in args.tree] or [["installed", ""]]
    work = Path(tempfile.mkdtemp(prefix="rbc_bench_cli_"))
    fiducials, targets = write_cell(work)
    commands = {"help": ["--help"],
                "register": ["register", str(fiducials), "--targets", str(targets)]}
    if args.only:
        commands = {args.only: commands[args.only]}
    times: dict[tuple[str, str], list[float]] = {}
    for _ in range(args.repeats):
        for name, argv_ in commands.items():
            for tree, path in trees:
                env = dict(os.environ)
                env.pop("OPENBLAS_NUM_THREADS", None)   # as a user's shell has it
                if path:
                    env["PYTHONPATH"] = str(Path(path).resolve())
                t0 = time.perf_counter()
                proc = subprocess.run([script, *argv_], env=env, cwd=work, capture_output=True,
                                      text=True)
                elapsed = time.perf_counter() - t0
                if proc.returncode != 0:
                    print(proc.stderr, file=sys.stderr)
                    return 1
                times.setdefault((name, tree), []).append(elapsed)
    shutil.rmtree(work, ignore_errors=True)
    print(f"{'command':<10} {'tree':<12} {'runs':>4} {'min [s]':>8} {'median [s]':>10}")
    for (name, tree), values in times.items():
        print(f"{name:<10} {tree:<12} {len(values):>4} {min(values):>8.3f} "
              f"{statistics.median(values):>10.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
