"""The report of a registration: a JSON-ready dict (keys documented in README.md) and its text."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike

from ..core.evaluation import TargetErrors, target_errors
from ..core.model import RbcModel
from ..pipeline.jsonable import json_number as _num
from ..pipeline.jsonable import json_vector as _vec
from ..pipeline.jsonable import registration_json
from .escape import terminal


def _summary(err: Optional[TargetErrors]) -> dict[str, Any]:
    if err is None or len(err.tre_u) == 0:
        return {"tre_u_median": None, "tre_c_median": None, "fraction_improved": None}
    return {k: _num(v) for k, v in err.summary().items()}


def model_report(model: RbcModel, target_ids: Sequence[str] = (),
                 targets_working: Optional[ArrayLike] = None,
                 targets_destination: Optional[ArrayLike] = None,
                 loo: Optional[TargetErrors] = None, unit: str = "mm") -> dict[str, Any]:
    """Build the report dict of ``register`` / ``evaluate`` (README "JSON report")."""
    cfg = model.config
    report: dict[str, Any] = {
        "unit": unit,
        "dim": cfg.dimension,
        "n_fiducials": len(model.ids),
        "n_measurements": int(model.counts.sum()),
        "restoration": cfg.restoration,
        "steps": cfg.steps if cfg.restoration == "iterative" else 1,
        "interpolation": cfg.interpolation,
        "sigma": _num(model.sigma),
        "sigma_source": model.sigma_source,
        "sigma_L": [_num(v) for v in model.sigma_l],
        "rho": _num(model.rho),
        "recommendation": model.recommendation,
        "uncorrected": registration_json(model.uncorrected),
        "corrected": registration_json(model.corrected),
        "fiducials": [{"id": fid, "correction": _vec(eps), "n": int(n)}
                      for fid, eps, n in zip(model.ids, model.corrections, model.counts)],
        "targets": [],
        "summary": _summary(None),
    }
    if targets_working is not None and len(target_ids):
        tc = model.correct(targets_working)
        err = (target_errors(model, targets_working, targets_destination)
               if targets_destination is not None else None)
        for k, tid in enumerate(target_ids):
            entry = {"id": tid, "uncorrected": _vec(tc.uncorrected[k]),
                     "corrected": _vec(tc.corrected[k]), "correction": _vec(tc.correction[k]),
                     "inside_hull": bool(tc.inside_hull[k]),
                     "expected_error": _num(tc.expected_error[k])}
            if err is not None:
                entry.update(tre_u=_num(err.tre_u[k]), tre_c=_num(err.tre_c[k]))
            report["targets"].append(entry)
        report["summary"] = _summary(err)
    if loo is not None:
        report["loo"] = {**{k: v for k, v in _summary(loo).items() if k != "fraction_improved"},
                         "fraction_improved": _summary(loo)["fraction_improved"],
                         "fiducials": [{"id": fid, "tre_u": _num(u), "tre_c": _num(c)}
                                       for fid, u, c in zip(model.ids, loo.tre_u, loo.tre_c)]}
    return report


def write_json(report: dict[str, Any], path: Path | str) -> None:
    """Write a report as indented JSON (NaN never appears: it is null)."""
    Path(path).write_text(json.dumps(report, indent=2, allow_nan=False) + "\n")


def _fmt(v: Any, unit: str = "") -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float):
        return f"{v:.4g}{(' ' + unit) if unit else ''}"
    return str(v)


def format_report(report: dict[str, Any]) -> str:
    """A readable text version of a report dict (ids and unit escaped for the terminal)."""
    u = terminal(report["unit"])
    sig_l = ", ".join(f"{v:.3g}" if v is not None else "n/a" for v in report["sigma_L"])
    lines = [
        f"Registration of {report['n_fiducials']} fiducials ({report['n_measurements']} "
        f"measurements), {report['dim']}D, lengths in {u}",
        f"  restoration {report['restoration']} ({report['steps']} step(s)), "
        f"interpolation {report['interpolation']}",
        f"  sigma        {_fmt(report['sigma'], u)} ({report['sigma_source']})",
        f"  sigma_L      {sig_l} {u}  (before, after each step; eq. 7)",
        f"  rho          {_fmt(report['rho'])} -> {report['recommendation']}",
        f"  FRE rms      uncorrected {_fmt(report['uncorrected']['fre_rms'], u)}, "
        f"corrected {_fmt(report['corrected']['fre_rms'], u)}",
    ]
    if report["targets"]:
        truth = "tre_u" in report["targets"][0]
        lines.append("")
        head = f"  {'target':<10} {'correction |eps|':>16} {'hull':>5}"
        if truth:
            head += f" {'TRE_u':>10} {'TRE_c':>10} {'dTRE':>10}"
        lines.append(head)
        for t in report["targets"]:
            eps = float(np.linalg.norm(np.array(t["correction"], float)))
            row = (f"  {terminal(t['id']):<10} {eps:>16.4g} "
                   f"{'in' if t['inside_hull'] else 'OUT':>5}")
            if truth:
                row += f" {t['tre_u']:>10.4g} {t['tre_c']:>10.4g} {t['tre_c'] - t['tre_u']:>+10.3g}"
            lines.append(row)
        s = report["summary"]
        if s["tre_u_median"] is not None:
            lines.append(f"  median TRE_u {_fmt(s['tre_u_median'], u)}, TRE_c "
                         f"{_fmt(s['tre_c_median'], u)}; improved "
                         f"{100 * s['fraction_improved']:.0f}% of targets")
    if "loo" in report:
        lo = report["loo"]
        lines.append(f"  leave-one-out: median TRE_u {_fmt(lo['tre_u_median'], u)}, TRE_c "
                     f"{_fmt(lo['tre_c_median'], u)}; improved "
                     f"{100 * lo['fraction_improved']:.0f}% of fiducials")
    return "\n".join(lines)
