"""The demo a new user runs first (``scripts/demo.sh``): a synthetic RA-like cell (robot arm,
2D, 277 fiducial holes, 80 target holes) is written as a bag, replayed into a live
``registration_node``, the node corrects all targets, and the TRE with and without correction
is printed beside the rho decision; then ``evaluate`` writes the report directory offline and
the two are compared. The node is always stopped (also on Ctrl-C or an error).

Run with the loopback environment of ``scripts/env.sh`` (DDS stays on this machine).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable, Optional, Sequence

import numpy as np

from ..core.constants import MM_PER_M
from ..core.decision.noise import format_rho
from ..core.synthetic.cells import make_cell
from ..io.bag.reader import read_bag
from ..io.bag.records import DEFAULT_TOPICS
from ..io.bag.synthetic import cell_messages
from ..io.bag.writer import write_bag
from ..io.evaluation import evaluate_contents, write_report_dir
from ..pipeline.offline import settings_for
from ..pipeline.settings import SPECS
from .demo_client import NODE, DemoClient, DemoError
from .process import start_node, stop_process


def _start_node(state_dir: str, log_path: Path) -> subprocess.Popen:
    with open(log_path, "w") as log:
        return start_node(NODE, {"dimension": 2, "state_dir": state_dir,
                                 "debounce_period": 0.1}, log=log)


def _fresh_bag_path(out: Path) -> Path:
    bag = out / "ra_cell_bag"
    if bag.exists():
        if not (bag / "metadata.yaml").exists():
            raise DemoError(f"{bag} exists and is not a bag; move it away")
        shutil.rmtree(bag)
    return bag


def run(out: Path, rate: float = 20.0, seed: int = 0, timeout: float = 60.0,
        log: Callable[[str], None] = print) -> dict[str, Any]:
    """The demo; returns what it printed as a dict (also written to ``out/demo.json``)."""
    t0 = time.monotonic()
    out.mkdir(parents=True, exist_ok=True)
    cell = make_cell("RA", seed=seed)
    n_meas = sum(len(m) for m in cell.fiducial_measurements)
    bag = _fresh_bag_path(out)
    log(f"[1/5] synthetic RA-like cell (seed {seed}): {len(cell.fiducial_ids)} fiducial holes "
        f"({n_meas} measurements, 20 ms apart), {len(cell.target_ids)} targets -> {bag}")
    write_bag(bag, cell_messages(cell), "mcap", progress=False)
    contents = read_bag(bag, progress=False)
    truth = np.array([m.destination[:2] for m in contents.targets])
    working = np.array([m.working[:2] for m in contents.targets])

    node = client = None
    state_dir = tempfile.mkdtemp(prefix="rbc_demo_state_")
    try:
        log(f"[2/5] starting registration_node (dimension:=2, state_dir:={state_dir}); "
            f"log {out / 'node.log'}")
        node = _start_node(state_dir, out / "node.log")
        client = DemoClient()
        client.wait_status(lambda s: True, timeout, "the node's first status", node)

        log(f"[3/5] replaying {bag.name} at {rate:g}x into /{NODE}/fiducial_pairs")
        from .replay import replay

        result = replay(bag, rate=rate, topics=[DEFAULT_TOPICS.fiducial_pairs], wait=10.0,
                        context=client.context, progress=False, log=log)
        log(f"      published {result.published} messages in {result.seconds:.1f} s; waiting "
            "for the model")
        status = client.wait_status(
            lambda s: (s.n_measurements + s.n_rejected >= n_meas and s.n_pending == 0
                       and s.model_valid and s.n_fiducials == len(cell.fiducial_ids)),
            timeout, f"all {len(cell.fiducial_ids)} fiducials in the model", node)

        log(f"[4/5] correct_targets for all {len(working)} targets")
        response = client.correct_targets(working)
        if not response.success:
            raise DemoError(f"correct_targets failed: {response.message}")
        corrected, tre_u, tre_c, applied = _targets_report(response, truth, status, log)

        log(f"[5/5] offline: evaluate {bag.name} -> {out}/")
        diff, agree = _offline_agrees(contents, out, corrected, status.rho, log)
    finally:
        if client is not None:
            client.close()
        stop_process(node, timeout=10)
        shutil.rmtree(state_dir, ignore_errors=True)
    summary = {"rho": status.rho, "recommendation": status.recommendation,
               "corrections_applied": applied, "n_fiducials": status.n_fiducials,
               "n_measurements": status.n_measurements, "unit": "mm",
               "tre_u_median": float(np.median(tre_u)), "tre_c_median": float(np.median(tre_c)),
               "fraction_improved": float(np.mean(tre_c < tre_u)),
               "targets": [{"id": tid, "tre_u": float(u), "tre_c": float(c)}
                           for tid, u, c in zip(cell.target_ids, tre_u, tre_c)],
               "offline_max_difference_m": diff, "agree": agree,
               "seconds": time.monotonic() - t0}
    (out / "demo.json").write_text(json.dumps(summary, indent=2) + "\n")
    log(f"done in {summary['seconds']:.1f} s: {out}/report.md, figures, report.json, demo.json, "
        "node.log; the node is stopped")
    return summary


def _targets_report(response: Any, truth: np.ndarray, status: Any,
                    log: Callable[[str], None]) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """Step 4's lines: rho, the decision and the targets' TRE [mm] uncorrected and corrected;
    returns (corrected points [m], TRE uncorrected, TRE corrected, corrections applied)."""
    corrected = np.array([[r.corrected.point.x, r.corrected.point.y] for r in response.results])
    uncorrected = np.array([[r.uncorrected.point.x, r.uncorrected.point.y]
                            for r in response.results])
    tre_u = np.linalg.norm(uncorrected - truth, axis=1) * MM_PER_M
    tre_c = np.linalg.norm(corrected - truth, axis=1) * MM_PER_M
    applied = bool(response.results[0].correction_applied)
    rho = format_rho(status.rho, SPECS["rho_reject"].default, SPECS["rho_apply"].default)
    log(f"      rho = sigma_L0 / sigma = {rho} (sigma_L0 "
        f"{status.sigma_l[0] * MM_PER_M:.3g} mm, sigma {status.sigma * MM_PER_M:.3g} mm from "
        f"{status.sigma_source}) -> the paper's rule: {status.recommendation}")
    log(f"      decision ({status.decision_mode}): {status.decision_method}, corrections "
        f"{'applied' if applied else 'not applied'}")
    log("      TRE [mm]       median    mean     max")
    log(f"      uncorrected  {np.median(tre_u):7.3f} {tre_u.mean():7.3f} {tre_u.max():7.3f}")
    log(f"      corrected    {np.median(tre_c):7.3f} {tre_c.mean():7.3f} {tre_c.max():7.3f}")
    log(f"      corrections improved {np.mean(tre_c < tre_u) * 100:.0f}% of targets")
    return corrected, tre_u, tre_c, applied


def _offline_agrees(contents: Any, out: Path, corrected: np.ndarray, rho: float,
                    log: Callable[[str], None]) -> tuple[float, bool]:
    """Step 5: the bag through ``evaluate`` (report in ``out``); returns the largest difference
    [m] of its corrected targets from the node's and whether the two agree (and rho)."""
    ev = evaluate_contents(contents, settings_for(2, {}))
    write_report_dir(ev, out, "Demo: RA-like cell")
    offline = np.array([t["corrected"] for t in ev.report["targets"]])
    diff = float(np.abs(offline - corrected).max())
    rho_diff = abs(ev.model.rho - rho)
    agree = diff < 1e-9 and rho_diff < 1e-9
    log(f"      live node vs offline evaluate: max |corrected| difference {diff:.2g} m, "
        f"rho difference {rho_diff:.2g} -> {'agree' if agree else 'DIFFER'}")
    return diff, agree


def main(argv: Optional[Sequence[str]] = None) -> int:
    """``python -m rbc_registration.ros.demo [--out DIR] [--rate R]``; exit 1 when live and
    offline results differ or a step failed, 130 on Ctrl-C."""
    p = argparse.ArgumentParser(prog="rbc_registration.ros.demo",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=Path("demo_out"), help="report directory")
    p.add_argument("--rate", type=float, default=20.0, help="replay speed-up (default 20)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--timeout", type=float, default=60.0, help="seconds per waiting step")
    args = p.parse_args(argv)
    try:
        summary = run(args.out, args.rate, args.seed, args.timeout)
    except KeyboardInterrupt:
        print("demo: interrupted; the node is stopped", file=sys.stderr)
        return 130
    except (DemoError, ValueError, OSError, ImportError) as exc:
        print(f"demo: error: {exc}", file=sys.stderr)
        return 1
    return 0 if summary["agree"] else 1


if __name__ == "__main__":
    sys.exit(main())
