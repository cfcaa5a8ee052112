"""``rbc-registration reproduce``: the paper's Table 1 and Figs 2-5 on synthetic cells.

Prints the Table 1 analogue and the findings it checks, writes ``table1.md``,
``reproduce.json`` and PNG figures for both interpolations into the output directory.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable, Optional

import numpy as np

from ..core.constants import CANDIDATES, CELLS, INTERPOLATIONS
from ..core.synthetic.experiments import CellResult, run_cell
from ..core.model import ModelConfig
from ..core.decision.noise import format_rho
from ..core.synthetic.cells import make_cell
from . import figures
from .escape import terminal


def findings(results: dict[str, CellResult]) -> list[dict[str, Any]]:
    """The paper's findings (and the kriging claims) evaluated on the results."""
    out = []

    def add(name: str, value: float, limit: float, holds: bool, text: str) -> None:
        out.append({"finding": name, "value": float(value), "limit": float(limit),
                    "holds": bool(holds), "text": text})

    for cell, r in results.items():
        s = r.model.sigma_l
        add(f"{cell}: sigma_L1/sigma_L0", s[1] / s[0], 2e-3, s[1] / s[0] <= 2e-3,
            "first step removes ~99.9% of the mismatch (Table 1: ~1e-3 or smaller)")
        add(f"{cell}: sigma_L2/sigma_L0", s[2] / s[0], 1e-6, s[2] / s[0] < 1e-6,
            "second step restores RBC (Table 1: below 1e-6)")
    if "A" in results:
        p = results["A"].results["paper"].averaged.summary()
        ratio = p["tre_c_median"] / p["tre_u_median"]
        add("A: median TRE_c / TRE_u (paper, averaged)", ratio, 0.5, ratio < 0.5,
            "large TRE reduction for A-like (Fig. 4a)")
    if "B" in results:
        r = results["B"].results["paper"]
        if r.instantaneous_tre_c is not None:
            inst_c = float(np.median(r.instantaneous_tre_c))
            avg_u = r.averaged.summary()["tre_u_median"]
            add("B: median TRE_c^(n) / TRE_u (paper; instantaneous corrected vs uncorrected)",
                inst_c / avg_u, 1.0, inst_c > avg_u,
                "corrected instantaneous TRE is worse than uncorrected (Fig. 4b, cases 3 vs 1)")
            k = results["B"].results["kriging"]
            ratio = float(np.median(k.instantaneous_tre_c) / np.median(k.instantaneous_tre_u))
            add("B: median TRE_c^(n) / TRE_u^(n) (kriging, instantaneous)", ratio, 1.01,
                ratio <= 1.01, "kriging does not make B-like worse (within 1%)")
    if "RA" in results:
        f = results["RA"].results["paper"].averaged.summary()["fraction_improved"]
        add("RA: fraction of targets improved (paper)", f, 0.75, f >= 0.75,
            "RA-like improved for at least 75% of targets (Fig. 5b)")
    # A only: on RA's single measurements kriging and the paper's interpolation are within about
    # 10 % of each other either way, seed by seed, so no order is claimed there; the decision
    # chooses per cell.
    if "A" in results:
        pc = results["A"].results["paper"].averaged.summary()["tre_c_median"]
        kc = results["A"].results["kriging"].averaged.summary()["tre_c_median"]
        add("A: median TRE_c kriging / paper", kc / pc, 1.0, kc <= pc,
            "kriging no worse than the paper's interpolation")
    return out


def destination_tre(r: CellResult) -> np.ndarray:
    """TRE per target of the point the decision gives (``destination``), averaged data."""
    tc = r.model.correct(r.cell.target_means)
    return np.linalg.norm(tc.destination - r.cell.target_truth, axis=1)


def _cell_json(r: CellResult) -> dict[str, Any]:
    m = r.model
    out: dict[str, Any] = {
        "sigma": m.sigma, "sigma_axis": m.sigma_axis, "sigma_L": list(m.sigma_l), "rho": m.rho,
        "recommendation": m.recommendation, "decision": m.decision.to_dict(),
        "tre_destination_median": float(np.median(destination_tre(r))),
        "n_fiducials": len(m.ids),
        "n_targets": len(r.cell.target_ids), "repeats": r.cell.spec.repeats,
        "instantaneous_sets": None if r.instantaneous_mismatch is None
        else int(r.instantaneous_mismatch[0].shape[0]),
        "interpolations": {}}
    for name, res in r.results.items():
        e = res.averaged
        entry: dict[str, Any] = {"summary": e.summary(), "targets": [
            {"id": tid, "tre_u": float(u), "tre_c": float(c)}
            for tid, u, c in zip(r.cell.target_ids, e.tre_u, e.tre_c)]}
        if res.instantaneous_tre_c is not None:
            entry["instantaneous"] = {
                "tre_u_median": float(np.median(res.instantaneous_tre_u)),
                "tre_c_median": float(np.median(res.instantaneous_tre_c)),
                "tre_u_per_target": res.instantaneous_tre_u.tolist(),
                "tre_c_per_target": res.instantaneous_tre_c.tolist()}
        out["interpolations"][name] = entry
    return out


def table(results: dict[str, CellResult]) -> str:
    """Table 1 analogue plus TRE medians, as Markdown."""
    rows = ["| cell | sigma [mm] | sigma_L0 [mm] | rho | sigma_L1 [mm] | sigma_L2 [mm] "
            "| rho rule | decision (cv) | CV median u / paper / kriging [mm] | TRE median of "
            "the decision [mm] |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    for cell, r in results.items():
        m = r.model
        d = m.decision
        cv = " / ".join("n/a" if s is None or not s.available else f"{s.cv_median:.3g}"
                        for s in map(d.candidate, CANDIDATES))
        rho = format_rho(m.rho, m.config.rho_reject, m.config.rho_apply)
        rows.append(f"| {cell} | {m.sigma:.3g} | {m.sigma_l[0]:.3g} | {rho} | "
                    f"{m.sigma_l[1]:.2g} | {m.sigma_l[2]:.2g} | {m.recommendation} | "
                    f"{d.method}{'' if d.confident else ' (uncertain)'} | {cv} | "
                    f"{np.median(destination_tre(r)):.3g} |")
    rows += ["", "| cell | interpolation | TRE_u median | TRE_c median | improved | "
             "TRE_u^(n) median | TRE_c^(n) median |", "|---|---|---|---|---|---|---|"]
    for cell, r in results.items():
        for name, res in r.results.items():
            s = res.averaged.summary()
            inst = ("| n/a | n/a |" if res.instantaneous_tre_c is None else
                    f"| {np.median(res.instantaneous_tre_u):.3g} | "
                    f"{np.median(res.instantaneous_tre_c):.3g} |")
            rows.append(f"| {cell} | {name} | {s['tre_u_median']:.3g} | {s['tre_c_median']:.3g} "
                        f"| {100 * s['fraction_improved']:.0f}% {inst}")
    return "\n".join(rows)


def write_figures(results: dict[str, CellResult], out: Path) -> list[Path]:
    """Figs 2-5 analogues for every cell and both interpolations."""
    paths = []
    for cell, r in results.items():
        unit = r.cell.unit
        inst = r.instantaneous_mismatch
        n_hist = 2 if inst is not None else len(r.mismatch)
        fig = "fig2" if inst is not None else "fig3"
        paths.append(figures.mismatch_histograms(
            out / f"{fig}_{cell}_histograms.png", r.mismatch[:n_hist], r.histogram_edges[:n_hist],
            f"Cell {cell}: histograms of L", unit, inst[:n_hist] if inst is not None else None))
        ids = r.cell.target_ids
        for name, res in r.results.items():
            e = res.averaged
            if res.instantaneous_tre_c is not None:
                series = {"(1) TRE_u, averaged": e.tre_u, "(2) TRE_c, averaged": e.tre_c,
                          "(3) median TRE_c^(n), instantaneous": res.instantaneous_tre_c,
                          "median TRE_u^(n), instantaneous": res.instantaneous_tre_u}
                paths.append(figures.tre_per_target(out / f"fig4_{cell}_{name}_tre.png", ids,
                                                    series, f"Cell {cell}, {name}", unit))
            else:
                series = {"(1) TRE_u": e.tre_u, "(2) TRE_c": e.tre_c}
                paths.append(figures.tre_per_target(out / f"fig5a_{cell}_{name}_tre.png", ids,
                                                    series, f"Cell {cell}, {name}", unit))
            paths.append(figures.delta_tre(out / f"fig5b_{cell}_{name}_dtre.png", ids, e.delta,
                                           f"Cell {cell}, {name}: dTRE = TRE_c - TRE_u", unit))
    return paths


def reproduce(out: Path, seed: int = 0, repeats: Optional[int] = None,
              instantaneous_sets: Optional[int] = None, cells=CELLS,
              config: Optional[ModelConfig] = None,
              log: Callable[[str], None] = print) -> dict[str, Any]:
    """Run the synthetic cells, print and write everything; return the JSON dict."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for cell in cells:
        log(f"cell {cell}: generating and processing ...")
        results[cell] = run_cell(make_cell(cell, seed=seed, repeats=repeats), config,
                                 instantaneous_sets, progress=log)
    text = table(results)
    found = findings(results)
    log("\nTable 1 analogue (synthetic cells, seed %d; lengths in mm)\n" % seed)
    log(text)
    log("\nFindings:")
    for f in found:
        log(f"  [{'holds' if f['holds'] else 'FAILS'}] {f['finding']} = {f['value']:.3g} "
            f"(limit {f['limit']:g}): {f['text']}")
    paths = write_figures(results, out)
    (out / "table1.md").write_text(text + "\n")
    doc = {"seed": seed, "unit": "mm", "interpolations": list(INTERPOLATIONS),
           "cells": {c: _cell_json(r) for c, r in results.items()}, "findings": found,
           "figures": [p.name for p in paths]}
    (out / "reproduce.json").write_text(json.dumps(doc, indent=2) + "\n")
    log(f"\nwrote {terminal(out / 'table1.md')}, {terminal(out / 'reproduce.json')} and "
        f"{len(paths)} figures")
    return doc
