"""Draw the README's figure: the target error of the example 3D cell, per target, with the rigid
registration alone and with the corrections (``docs/figures/cell3d_tre.png``).

The figure is drawn from the report of
``rbc-registration register examples/cell3d/fiducials.csv --targets examples/cell3d/targets.csv``
(run here, its JSON in a temporary directory): per target the error against the file's truth of
the uncorrected registration, of the paper's interpolation, and of the point to use (the
decision's method), with the point to use's 95 % bound.

Usage: ``python examples/make_figure.py [--out docs/figures/cell3d_tre.png]``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
from pathlib import Path

from rbc_registration.cli import main as cli_main
from rbc_registration.io.figures import tre_per_target

HERE = Path(__file__).resolve().parent
DEFAULT_OUT = HERE.parent / "docs" / "figures" / "cell3d_tre.png"


def report(directory: Path) -> dict:
    """The JSON report of ``register`` on the example 3D cell with its targets."""
    out = directory / "cell3d.json"
    with contextlib.redirect_stdout(io.StringIO()):
        status = cli_main(["register", str(HERE / "cell3d" / "fiducials.csv"),
                           "--targets", str(HERE / "cell3d" / "targets.csv"),
                           "--json", str(out)])
    if status != 0:
        raise SystemExit(f"make_figure: register ended with exit {status}")
    return json.loads(out.read_text(encoding="utf-8"))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT,
                        help="the PNG to write (default: docs/figures/cell3d_tre.png)")
    out = parser.parse_args(argv).out
    with tempfile.TemporaryDirectory() as tmp:
        data = report(Path(tmp))
    targets = data["targets"]
    method = data["decision"]["method"]
    series = {
        "uncorrected (rigid fit alone)": [t["tre_u"] for t in targets],
        f"corrected, {data['interpolation']} interpolation": [t["tre_c"] for t in targets],
        f"the point to use ({method}, the decision)": [t["tre"] for t in targets],
        f"its 95 % bound ({method})": [t["tre_bound"] for t in targets],
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    tre_per_target(out, [t["id"] for t in targets], series,
                   f"examples/cell3d: {data['n_fiducials']} fiducials, {len(targets)} targets",
                   data["unit"])
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
