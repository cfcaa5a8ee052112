"""The report of a registration: a JSON-ready dict (keys documented in docs/CLI.md) and its text."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike

from ..core.constants import UNCORRECTED
from ..core.decision.evaluation import TargetErrors, target_errors
from ..core.model import RbcModel
from ..core.decision.noise import format_rho
from ..core.rigid.quaternion import quaternion_from_matrix, rpy_from_matrix
from ..pipeline.jsonable import json_number as _num
from ..pipeline.jsonable import json_vector as _vec
from ..pipeline.jsonable import registration_json
from ..pipeline.targets import with_truth
from .escape import terminal


def _summary(err: Optional[TargetErrors]) -> dict[str, Any]:
    if err is None or len(err.tre_u) == 0:
        return {"tre_u_median": None, "tre_c_median": None, "fraction_improved": None}
    return {k: _num(v) for k, v in err.summary().items()}


def _destination_summary(tre: Optional[np.ndarray], bound: np.ndarray) -> dict[str, Any]:
    """Median TRE of the points to use, and the share of targets within their 95 % bound."""
    if tre is None or len(tre) == 0:
        return {"tre_median": None, "fraction_within_bound": None}
    finite = np.isfinite(bound)
    within = float(np.mean(tre[finite] <= bound[finite])) if finite.any() else None
    return {"tre_median": _num(float(np.median(tre))), "fraction_within_bound": _num(within)}


def chosen_registration_json(model: RbcModel) -> dict[str, Any]:
    """The registration targets get (the report's ``registration``): ``name``
    (``uncorrected`` when the decision's method is, else ``corrected``), ``method`` (the
    decision's: ``uncorrected``, or the interpolation whose corrections targets get on top of
    it), and the transform ``destination = R @ working + t`` by ``translation`` (t, d numbers,
    unit of the points), ``quaternion`` (x, y, z, w of R; 2D: about z) and ``rpy_deg`` (roll,
    pitch, yaw of R in degrees, fixed axes X, Y, Z: REP 103, tf2's ``getRPY``, URDF's
    ``rpy``)."""
    name = UNCORRECTED if model.decision.method == UNCORRECTED else "corrected"
    reg = model.uncorrected if name == UNCORRECTED else model.corrected
    return {"name": name, "method": model.decision.method, "translation": _vec(reg.translation),
            "quaternion": list(quaternion_from_matrix(reg.rotation)),
            "rpy_deg": [_num(float(np.degrees(a)) + 0.0) for a in rpy_from_matrix(reg.rotation)]}


def _ids(model: RbcModel, subset: Optional[Sequence[int]]) -> Optional[list[str]]:
    return None if subset is None else [model.ids[i] for i in subset]


def model_report(model: RbcModel, target_ids: Sequence[str] = (),
                 targets_working: Optional[ArrayLike] = None,
                 targets_destination: Optional[ArrayLike] = None,
                 loo: Optional[TargetErrors] = None, unit: str = "mm") -> dict[str, Any]:
    """Build the report dict of ``register`` / ``evaluate`` (docs/CLI.md, "JSON report")."""
    cfg = model.config
    report: dict[str, Any] = {
        "unit": unit,
        "dim": cfg.dimension,
        "n_fiducials": len(model.ids),
        "n_measurements": int(model.counts.sum()),
        "restoration": cfg.restoration,
        "steps": cfg.steps if cfg.restoration == "iterative" else 1,
        "interpolation": cfg.interpolation,
        # the fiducial ids each registration was fitted to (null: all of them)
        "uncorrected_fit": _ids(model, cfg.uncorrected_subset),
        "corrected_fit": _ids(model, cfg.corrected_subset),
        "sigma": _num(model.sigma),
        "sigma_axis": _num(model.sigma_axis),
        "sigma_source": model.sigma_source,
        "sigma_L": [_num(v) for v in model.sigma_l],
        "rho": _num(model.rho),
        "rho_thresholds": [cfg.rho_reject, cfg.rho_apply],
        "recommendation": model.recommendation,
        "decision": model.decision.to_dict(),
        "registration": chosen_registration_json(model),
        "uncorrected": registration_json(model.uncorrected),
        "corrected": registration_json(model.corrected),
        "fiducials": [{"id": fid, "correction": _vec(eps), "n": int(n)}
                      for fid, eps, n in zip(model.ids, model.corrections, model.counts)],
        "targets": [],
        "summary": {**_summary(None), **_destination_summary(None, np.empty(0))},
    }
    if targets_working is not None and len(target_ids):
        tc = model.correct(targets_working)
        # truth per target: a row of NaN is a target without truth (a bag's target message
        # with a NaN destination); TRE and the summary are over the targets with truth
        truth = (None if targets_destination is None
                 else np.asarray(targets_destination, float)[:, :cfg.dimension])
        has = with_truth(truth, len(target_ids))
        err = (target_errors(model, np.asarray(targets_working, float)[has], truth[has])
               if has.any() else None)
        tre = (np.linalg.norm(tc.destination[has] - truth[has], axis=1)
               if err is not None else None)
        at = np.cumsum(has) - 1                 # a target's row among those with truth
        for k, tid in enumerate(target_ids):
            entry = {"id": tid, "destination": _vec(tc.destination[k]),
                     "expected_tre": _num(tc.expected_tre[k]), "tre_bound": _num(tc.tre_bound[k]),
                     "uncorrected": _vec(tc.uncorrected[k]),
                     "corrected": _vec(tc.corrected[k]), "correction": _vec(tc.correction[k]),
                     "inside_hull": bool(tc.inside_hull[k]),
                     "expected_error": _num(tc.expected_error[k])}
            if err is not None and has[k]:
                i = at[k]
                entry.update(tre=_num(tre[i]), tre_u=_num(err.tre_u[i]), tre_c=_num(err.tre_c[i]))
            elif err is not None:               # no truth for this one: no TRE
                entry.update(tre=None, tre_u=None, tre_c=None)
            report["targets"].append(entry)
        report["summary"] = {**_summary(err), **_destination_summary(
            tre, tc.tre_bound[has] if err is not None else tc.tre_bound)}
    if loo is not None:
        report["loo"] = {**{k: v for k, v in _summary(loo).items() if k != "fraction_improved"},
                         "fraction_improved": _summary(loo)["fraction_improved"],
                         "fiducials": [{"id": fid, "tre_u": _num(u), "tre_c": _num(c)}
                                       for fid, u, c in zip(model.ids, loo.tre_u, loo.tre_c)]}
    return report


def write_json(report: dict[str, Any], path: Path | str) -> None:
    """Write a report as indented JSON (NaN never appears: it is null); missing parent
    directories are created."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(json.dumps(report, indent=2, allow_nan=False) + "\n")


def _rho_text(report: dict[str, Any]) -> str:
    """rho as the text report shows it (null in JSON: unknown, sigma being unknown; a sigma of
    0 is refused when given and identical repeats give none, :func:`~rbc_registration.core.
    noise.identical_repeats`)."""
    if report["rho"] is None or "rho_thresholds" not in report:
        return _fmt(report["rho"])
    return format_rho(report["rho"], *report["rho_thresholds"], digits=4)


def _fmt(v: Any, unit: str = "") -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float):
        return f"{v:.4g}{(' ' + unit) if unit else ''}"
    return str(v)


def decision_lines(decision: dict[str, Any], unit: str) -> list[str]:
    """The decision of a report (its ``decision`` object) as text lines: mode, method, reason,
    and each candidate's cross-validated error."""
    folds = decision["folds"]
    name = ("leave-one-group-out" if folds.get("grouped") and folds["kind"] == "leave-one-out"
            else folds["kind"] + (" of whole groups" if folds.get("grouped") else ""))
    kind = f"{name}, {folds['n_folds']} folds" if folds["n_folds"] else name
    lines = [f"  decision     {decision['mode']} -> {decision['method']} (corrections "
             f"{'applied' if decision['apply'] else 'not applied'}"
             f"{'' if decision['confident'] else '; uncertain'})",
             f"  reason       {decision['reason']}",
             f"  cross-validated error per candidate ({kind}; {unit}):",
             f"    {'candidate':<12} {'median':>10} {'rms':>10} {'95% bound':>10} "
             f"{'p-value':>9}"]
    for name, c in decision["cv"].items():
        if not c["available"]:
            lines.append(f"    {name:<12} n/a ({c['note']})")
            continue
        p = "" if c["p_value"] is None else f"{c['p_value']:.2g}"
        lines.append(f"    {name:<12} {_fmt(c['median']):>10} {_fmt(c['rms']):>10} "
                     f"{_fmt(c['bound']):>10} {p:>9}")
    return lines


def _numbers(values: Sequence[Any]) -> str:
    """Numbers of a transform, 10 significant digits (to copy into a launch file or URDF)."""
    return ", ".join("n/a" if v is None else f"{float(v):.10g}" for v in values)


def registration_lines(reg: dict[str, Any], unit: str) -> list[str]:
    """The chosen registration of a report (its ``registration`` object) as text lines:
    translation (``unit``), quaternion x, y, z, w and roll, pitch, yaw in degrees."""
    axes = "x, y, z" if len(reg["translation"]) == 3 else "x, y"
    then = ("" if reg["method"] == UNCORRECTED
            else f", then each target's {reg['method']} correction")
    return [f"  registration {reg['name']} (destination = R working + t{then})",
            f"    translation  {axes} = {_numbers(reg['translation'])} {unit}",
            f"    quaternion   x, y, z, w = {_numbers(reg['quaternion'])}",
            f"    rpy          roll, pitch, yaw = {_numbers(reg['rpy_deg'])} deg (fixed axes "
            f"X, Y, Z: REP 103, tf2, URDF)"]


def _target_columns(report: dict[str, Any]) -> list[tuple[str, str]]:
    """The TRE columns of the target table, ``(method, JSON key)``: the decision's method
    (``tre``, the points to use), the uncorrected registration (``tre_u``) and the configured
    interpolation (``tre_c``), each method once."""
    columns: list[tuple[str, str]] = []
    for method, key in ((report["decision"]["method"], "tre"), (UNCORRECTED, "tre_u"),
                        (report["interpolation"], "tre_c")):
        if method not in (m for m, _ in columns):
            columns.append((method, key))
    return columns


def _point(value: Any) -> str:
    """A coordinate of a point to use, 9 significant digits (to copy into a robot program)."""
    return "n/a" if value is None else f"{float(value):.9g}"


def _target_lines(report: dict[str, Any], u: str) -> list[str]:
    """The target table, every column named by its method, and its summary: the point to use
    (``destination``) with its expected error and bound, then the configured interpolation's
    correction, the hull and, with truth, the errors of each method."""
    used, configured = report["decision"]["method"], report["interpolation"]
    truth = "tre_u" in report["targets"][0]
    cols = _target_columns(report) if truth else []
    axes = "xyz"[:report["dim"]]
    heads = ([f"{a} {used}" for a in axes] + [f"exp. TRE {used}", f"95% bound {used}",
                                              f"|eps| {configured}", "hull"]
             + [f"TRE {m}" for m, _ in cols] + ([f"dTRE {configured}"] if truth else []))
    widths = [12 if k < len(axes) else 5 if h == "hull" else max(10, len(h))
              for k, h in enumerate(heads)]
    widths = [max(w, len(h)) for w, h in zip(widths, heads)]
    lines = ["", f"  targets ({u}): the points to use are {used}'s (the decision): "
                 f"{', '.join(axes)} in the destination frame, their expected error and 95% "
                 f"bound; |eps| is {configured}'s (the configured interpolation)"
                 + (f"; dTRE {configured} = TRE {configured} - TRE {UNCORRECTED} (eq. 3)"
                    if truth else ""),
             f"  {'target':<10} " + " ".join(f"{h:>{w}}" for h, w in zip(heads, widths))]
    for t in report["targets"]:
        eps = float(np.linalg.norm(np.array(t["correction"], float)))
        cells = ([_point(v) for v in t["destination"]]
                 + [_fmt(t["expected_tre"]), _fmt(t["tre_bound"]), f"{eps:.4g}",
                    "in" if t["inside_hull"] else "OUT"])
        if truth and t["tre_u"] is None:        # this target has no truth
            cells += ["n/a"] * (len(cols) + 1)
        elif truth:
            cells += [f"{t[key]:.4g}" for _, key in cols] + [f"{t['tre_c'] - t['tre_u']:+.3g}"]
        lines.append(f"  {terminal(t['id']):<10} "
                     + " ".join(f"{c:>{w}}" for c, w in zip(cells, widths)))
    s = report["summary"]
    if s["tre_u_median"] is not None:
        medians = {"tre": s["tre_median"], "tre_u": s["tre_u_median"], "tre_c": s["tre_c_median"]}
        first, *rest = [f"{m} {_fmt(medians[key], u)}" for m, key in cols]
        lines.append(f"  median TRE {first} (the points to use)"
                     + "".join(f", {r}" for r in rest)
                     + f"; {configured} corrections improved "
                       f"{100 * s['fraction_improved']:.0f}% of targets")
    if truth and s["fraction_within_bound"] is not None:
        lines.append(f"  {100 * s['fraction_within_bound']:.0f}% of targets within their 95% "
                     f"bound ({used})")
    return lines


def format_report(report: dict[str, Any]) -> str:
    """A readable text version of a report dict (ids and unit escaped for the terminal): every
    figure of a target, a fiducial or a registration is named by the method it is of."""
    u = terminal(report["unit"])
    sig_l = ", ".join(f"{v:.3g}" if v is not None else "n/a" for v in report["sigma_L"])
    configured = report["interpolation"]
    lines = [
        f"Registration of {report['n_fiducials']} fiducials ({report['n_measurements']} "
        f"measurements), {report['dim']}D, lengths in {u}",
        f"  restoration {report['restoration']} ({report['steps']} step(s)); configured "
        f"interpolation {configured} (its corrections: |eps|, TRE {configured}); targets get "
        f"the decision's method",
        f"  sigma        {_fmt(report['sigma'], u)} per point, {_fmt(report['sigma_axis'], u)} "
        f"per axis ({report['sigma_source']})",
        f"  sigma_L      {sig_l} {u}  (before, after each step; eq. 7)",
        f"  rho          {_rho_text(report)} -> {report['recommendation']} (the paper's rule)",
        f"  FRE rms      uncorrected {_fmt(report['uncorrected']['fre_rms'], u)}, "
        f"corrected {_fmt(report['corrected']['fre_rms'], u)}",
        *decision_lines(report["decision"], u),
    ]
    if report.get("registration"):
        lines += registration_lines(report["registration"], u)
    if report["targets"]:
        lines += _target_lines(report, u)
    if "loo" in report:
        lo = report["loo"]
        lines.append(f"  leave-one-out: median TRE {UNCORRECTED} {_fmt(lo['tre_u_median'], u)}, "
                     f"{configured} {_fmt(lo['tre_c_median'], u)}; {configured} corrections "
                     f"improved {100 * lo['fraction_improved']:.0f}% of fiducials")
    return "\n".join(lines)
