"""The report of a measurement plan (``rbc-registration plan``): a JSON-ready dict (keys
documented in docs/CLI.md, "`plan`") and its text.

Lengths are in the unit of the files (the label ``unit``); the plan is
:class:`~rbc_registration.core.planning.planner.MeasurementPlan`.
"""

from __future__ import annotations

from typing import Any, Sequence

from ..core.planning.expected_error import ExpectedErrorModel
from ..core.planning.planner import MeasurementPlan, PlanConfig
from ..pipeline.jsonable import json_number as _num
from .escape import terminal


def plan_report(plan: MeasurementPlan, candidate_ids: Sequence[str], error_model:
                ExpectedErrorModel, config: PlanConfig, unit: str = "mm") -> dict[str, Any]:
    """The report dict of ``plan`` (docs/CLI.md, "`plan`").

    :param candidate_ids: (C,) the candidates' ids, in the order the plan indexes them. With
        groups (``plan.unit_labels``) each suggestion is a group: ``id`` and ``index`` are its
        first candidate's, ``group``, ``ids`` and ``indices`` all of them; every candidate
        carries its group's gain and rank, and ``groups`` lists the groups.
    :param error_model: the error model the plan was made with (reported: s, l, noise, whether
        the correction is applied).
    :param config: the plan's configuration (the stopping rule's thresholds).
    :raises ValueError: when ``candidate_ids`` does not match the plan's candidates.
    """
    members = plan.members or tuple((k,) for k in range(len(plan.gains)))
    if sum(len(m) for m in members) != len(candidate_ids):
        raise ValueError(f"{len(candidate_ids)} candidate ids for a plan of "
                         f"{sum(len(m) for m in members)} candidates")
    labels = plan.unit_labels
    rank = {int(u): r for r, u in enumerate(plan.ranking, start=1)}
    unit_of = {c: u for u, m in enumerate(members) for c in m}
    counts, curve = plan.error_curve
    befores = (plan.expected_now,) + plan.expected_after[:-1]

    def label(u: int) -> Any:
        return (labels[u] or None) if labels else None

    suggestions = []
    for r, (u, before, after) in enumerate(zip(plan.sequence, befores, plan.expected_after),
                                           start=1):
        row = {"rank": r, "id": candidate_ids[members[u][0]], "index": int(members[u][0]),
               "expected_after": _num(after), "gain": _num(before - after)}
        if labels:
            row.update(group=label(u), ids=[candidate_ids[c] for c in members[u]],
                       indices=[int(c) for c in members[u]])
        suggestions.append(row)
    check = plan.model_check
    report = {
        "unit": unit,
        "dim": error_model.dimension,
        "n_fiducials": plan.fiducial_count,
        "n_candidates": len(candidate_ids),
        "error_at": "targets" if plan.on_targets else "work_volume",
        "n_points": len(plan.points),
        "corrected": bool(error_model.corrected),
        "error_model": {"signal_std": _num(error_model.signal_std),
                        "length_scale": _num(error_model.length_scale),
                        "noise_axis_std": [_num(v ** 0.5) for v in
                                           error_model.noise_covariance.diagonal()],
                        "calibration": _num(error_model.calibration)},
        "candidate_repeats": plan.candidate_repeats,
        "target_repeats": plan.target_repeats,
        "within": config.within,
        "min_gain_fraction": config.min_gain_fraction,
        "min_gain_length": config.min_gain_length,
        "expected_now": _num(plan.expected_now),
        "expected_with_all": _num(plan.expected_with_all),
        "enough": bool(plan.enough),
        "enough_rule": plan.enough_rule,
        "enough_after": plan.enough_after,
        "reason": plan.reason,
        "model_check": None if check is None else check.to_dict(),
        "suggestions": suggestions,
        "candidates": [dict({"id": cid, "index": k, "gain": _num(plan.gains[unit_of[k]]),
                             "rank": rank[unit_of[k]]},
                            **({"group": label(unit_of[k])} if labels else {}))
                       for k, cid in enumerate(candidate_ids)],
        "error_curve": {"n_fiducials": [int(n) for n in counts],
                        "expected": [_num(v) for v in curve]},
    }
    if labels:
        report["groups"] = [{"group": label(u), "ids": [candidate_ids[c] for c in m],
                             "gain": _num(plan.gains[u]), "rank": rank[u]}
                            for u, m in enumerate(members)]
    return report


def _len(v: Any, unit: str) -> str:
    return "n/a" if v is None else f"{v:.4g} {unit}"


def format_plan(report: dict[str, Any]) -> str:
    """A readable text version of a :func:`plan_report` dict."""
    u = terminal(report["unit"])
    where = (f"{report['n_points']} targets" if report["error_at"] == "targets"
             else f"the work volume ({report['n_points']} points)")
    reg = "corrected" if report["corrected"] else "uncorrected"
    lines = [
        f"Plan from {report['n_fiducials']} fiducials, {report['dim']}D, "
        f"{report['n_candidates']} candidates; median target error over {where}, {reg} "
        f"registration; lengths in {u}",
        f"  each new fiducial measured {report['candidate_repeats']} time(s) and each target "
        f"{report['target_repeats']} (--candidate-repeats, --target-repeats)",
        f"  expected median target error now  {_len(report['expected_now'], u)}",
        "  suggestions (#: the candidate's position in CANDIDATES.csv, from 0):",
        f"  {'rank':>4}  {'candidate':<12} {'#':>5} {'expected after':>16} {'gain':>12} "
        f"{'gain %':>7}",
    ]
    before = report["expected_now"]
    for s in report["suggestions"]:
        pct = 100 * s["gain"] / before if before else 0.0
        lines.append(f"  {s['rank']:>4}  {terminal(s['id']):<12} {s['index']:>5} "
                     f"{s['expected_after']:>13.4g} {u:<2} "
                     f"{s['gain']:>9.4g} {u:<2} {pct:>6.2f}%")
        if len(s.get("ids", ())) > 1 or s.get("group"):
            lines.append(f"        group {terminal(s['group'] or '')}: "
                         + ", ".join(terminal(i) for i in s["ids"]))
        before = s["expected_after"]
    if report["expected_with_all"] is not None:
        lines.append(f"  with all {report['n_candidates']} candidates measured: "
                     f"{_len(report['expected_with_all'], u)}")
    check = report.get("model_check")
    if check is not None and check["available"]:
        lines.append(f"  error model check: {check['units']} held-out, cross-validated median "
                     f"{_len(check['cross_validated_median'], u)} against "
                     f"{_len(check['expected_held_out_median'], u)} expected (x{check['ratio']:.3g}"
                     f", the calibration); "
                     + ("trusted" if check["trustworthy"] else "not trusted"))
    elif check is not None:
        lines.append(f"  error model check: not available ({terminal(check['note'])})")
    lines += ["", f"  verdict: {report['reason']}"]
    return "\n".join(lines)
