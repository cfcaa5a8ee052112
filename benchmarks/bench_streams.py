"""Long inputs read as streams: ``register`` on long FIDUCIALS.csv files against the bare
``csv``-module read of the same file, and ``evaluate`` on long bags against rosbags' bare
read-and-deserialize of the same bag; wall time and peak RSS of each process, in one run
(each pair measured back to back, so the ratios share the machine's load).

    nice .venv/bin/python benchmarks/bench_streams.py [--rows 500000 3600000]
        [--repeats 1000 2000] [--dir /tmp/rbc_bench_streams]

``--rows``: CSV sizes (50 fiducials, repeats = rows / 50, a destination point per fiducial and
a noisy working point per row, 5 decimals). ``--repeats``: bags of ``synth-bag --cell B
--period 0.001`` (141 messages per repeat: 125 fiducial pairs, 16 targets). Prints a
Markdown table.
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np

PY = sys.executable

BARE_CSV = textwrap.dedent("""
    import csv, sys
    with open(sys.argv[1], newline="") as fh:
        rows = csv.reader(fh)
        next(rows)
        for row in rows:
            values = [float(x) for x in row[1:]]
""")

BARE_BAG = textwrap.dedent("""
    import sys
    from rosbags.rosbag2 import Reader
    from rbc_registration.io.bag.typestore import make_typestore
    store = make_typestore()
    with Reader(sys.argv[1]) as reader:
        for conn, _, raw in reader.messages():
            store.deserialize_cdr(raw, conn.msgtype)
""")


def write_csv(path: Path, rows: int, fiducials: int = 50) -> None:
    """A FIDUCIALS.csv of ``rows`` rows: ``fiducials`` points measured rows / fiducials times."""
    rng = np.random.default_rng(1)
    x = rng.uniform(0, 1000, (fiducials, 3))
    a = 0.3
    r = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    y = x @ r.T + [100, 200, 50] + rng.normal(0, 0.05, x.shape)
    dest = [[f"{v:.5f}" for v in p] for p in y]
    with path.open("w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(["id", "wx", "wy", "wz", "dx", "dy", "dz"])
        for _ in range(rows // fiducials):
            noisy = x + rng.normal(0, 0.01, x.shape)
            out.writerows([f"F{j:03d}", *(f"{v:.5f}" for v in noisy[j]), *dest[j]]
                          for j in range(fiducials))


def measure(args: list[str]) -> tuple[float, float, float]:
    """Wall time [s], CPU time (user + system) [s] and peak RSS [MB] of a child process."""
    start = time.perf_counter()
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    err = proc.stderr.read().decode() if proc.stderr else ""
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(args)} failed: {err}")
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024.0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, nargs="*", default=[500_000, 3_600_000])
    parser.add_argument("--repeats", type=int, nargs="*", default=[1000, 2000])
    parser.add_argument("--dir", type=Path, default=Path("/tmp/rbc_bench_streams"))
    args = parser.parse_args()
    args.dir.mkdir(parents=True, exist_ok=True)
    cli = [PY, "-m", "rbc_registration.cli"]
    lines = ["| input | size | bare read: wall (CPU) | wall (CPU) | ratio: wall (CPU) | "
             "bare RSS MB | RSS MB |", "|---|---:|---:|---:|---:|---:|---:|"]

    def row(what: str, size: str, bare: tuple, tool: tuple) -> str:
        return (f"| {what} | {size} | {bare[0]:.2f} s ({bare[1]:.2f} s) | {tool[0]:.2f} s "
                f"({tool[1]:.2f} s) | {tool[0] / bare[0]:.2f} ({tool[1] / bare[1]:.2f}) | "
                f"{bare[2]:.0f} | {tool[2]:.0f} |")

    rss = {}
    for rows in args.rows:
        path = args.dir / f"fiducials_{rows}.csv"
        if not path.exists():
            write_csv(path, rows)
        bare = measure([PY, "-c", BARE_CSV, str(path)])
        tool = measure(cli + ["register", str(path)])
        rss.setdefault("register", []).append(tool[2])
        lines.append(row("register CSV", f"{rows:,} rows", bare, tool))
        print(lines[-1], flush=True)
    for repeats in args.repeats:
        bag = args.dir / f"bag_B_{repeats}"
        if not bag.exists():
            subprocess.run(cli + ["synth-bag", str(bag), "--cell", "B", "--repeats",
                                  str(repeats), "--period", "0.001", "--storage", "mcap",
                                  "--quiet"], check=True, stdout=subprocess.DEVNULL)
        messages = 141 * repeats
        bare = measure([PY, "-c", BARE_BAG, str(bag)])
        tool = measure(cli + ["evaluate", str(bag), "--quiet"])
        rss.setdefault("evaluate", []).append(tool[2])
        lines.append(row("evaluate mcap bag", f"{messages:,} messages", bare, tool))
        print(lines[-1], flush=True)
    print()
    print("\n".join(lines))
    print(f"load average (1 min) at the end: {os.getloadavg()[0]:.1f}")
    for name, values in rss.items():
        if len(values) > 1:
            print(f"{name}: peak RSS of the largest / the smallest input "
                  f"{values[-1] / values[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
