"""The report of an offline evaluation of a recorded bag: the pipeline's model
(:func:`rbc_registration.pipeline.offline.evaluate_inputs`, the node's own ingestion and model
builder) with the report of ``register`` plus what the bag held, its text summary, and the
report directory (``report.json``, ``report.md``, PNG figures).

No rclpy: nothing here starts a ROS graph. Lengths in metres as in the bag (REP 103); figures and
the Markdown report show millimetres.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable, NamedTuple, Optional, Sequence, Union

import numpy as np

from ..core.measurements.accumulator import FiducialSet
from ..core.constants import MM_PER_M as MM
from ..core.decision.evaluation import leave_one_out, target_errors
from ..core.rigid.mismatch import pairwise_mismatch
from ..core.decision.noise import format_rho
from ..core.model import RbcModel
from ..core.measurements.sessions import SessionPlan
from ..pipeline.offline import evaluate_inputs
from ..pipeline.settings import Settings
from ..pipeline.targets import Targets, with_truth
from . import figures
from .bag.records import BagContents
from .escape import markdown as md_text
from .escape import markdown_code as md_code
from .escape import terminal
from .report import format_report, model_report, write_json


class Evaluation(NamedTuple):
    """The outcome of :func:`evaluate_contents`."""

    model: RbcModel
    fiducials: FiducialSet
    settings: Settings
    targets: Optional[Targets]
    report: dict[str, Any]
    rejected: dict[str, int]
    notes: tuple[str, ...]
    #: Lines to check, each a ``warning:`` line of ``evaluate`` (e.g. duplicates dropped).
    warnings: tuple[str, ...] = ()


def evaluate_contents(contents: BagContents, settings: Settings,
                      targets: Union[Targets, Callable[[Optional[SessionPlan]], Targets],
                                     None] = None,
                      loo: bool = False) -> Evaluation:
    """Accumulate, build the node's model and make the report (lengths in metres); with more
    than one session the report's ``sessions`` list is ``register``'s
    (:meth:`~rbc_registration.core.measurements.sessions.SessionPlan.to_list`).

    :param targets: targets to report, or a function of the fiducials' session plan giving
        them (default: the bag's targets topic, if any).
    :raises rbc_registration.pipeline.offline.EvaluationError: when no model can be built (too
        few fiducials, degenerate geometry) or the bag's targets cannot be used.
    """
    ev = evaluate_inputs(contents.inputs, settings, contents.targets, targets,
                         source=str(contents.path))
    targets = ev.targets
    loo_err = leave_one_out(ev.model) if loo else None
    report = model_report(ev.model, targets.ids if targets else (),
                          targets.working if targets else None,
                          targets.destination if targets else None, loo_err, "m")
    # the frames of the measurements the model was built from (the others were rejected)
    if ev.fiducials.sessions is not None:
        report["sessions"] = ev.fiducials.sessions.to_list()
    report["working_frame"] = settings.working_frame
    report["destination_frame"] = settings.destination_frame
    report["bag"] = {"path": str(contents.path), "messages": dict(contents.counts),
                     "rejected": ev.rejected, "disabled": list(ev.fiducials.disabled_ids),
                     "left_out": list(ev.fiducials.left_out_ids),
                     "targets_source": targets.source if targets else None,
                     "other_topics": dict(contents.other_topics)}
    out = Evaluation(ev.model, ev.fiducials, settings, targets, report, ev.rejected,
                     contents.count_mismatches + contents.notes + ev.notes)
    many = rejections_line(ev.rejected, dict(ev.first_rejections), len(contents.inputs))
    return with_warnings(out, tuple(w for w in (ev.warning, many) if w))


#: A warning names the rejections when they are at least this share of the input messages.
REJECTED_WARN_FRACTION = 0.1


def rejections_line(rejected: dict[str, int], first: dict[str, str], total: int) -> str:
    """The warning when at least :data:`REJECTED_WARN_FRACTION` of the ``total`` input messages
    were rejected, naming each reason's count and its first message (the model was built from
    the rest, as the node's would be), or "". Duplicates (copies, not lost measurements) and
    ambiguous points have lines of their own (:func:`duplicates_line`,
    :func:`ambiguous_points_line`) and are not counted."""
    rejected = {r: c for r, c in rejected.items() if c and r not in ("duplicate", "ambiguous")}
    n = sum(rejected.values())
    if not total or n < REJECTED_WARN_FRACTION * total:
        return ""
    top = max(rejected, key=lambda r: rejected[r])
    counts = ", ".join(f"{r} {c}" for r, c in sorted(rejected.items(), key=lambda rc: -rc[1]))
    return (f"{n} of {total} input message(s) rejected ({counts}), e.g. {top}: "
            f"{first.get(top, '?')}; the model is built from the rest, as the node's would be")


def ambiguous_points_line(ev: Evaluation, working_topic: str, destination_topic: str) -> str:
    """The warning when points were refused as ambiguous (two points of the other stream within
    ``pair_slop``, :mod:`rbc_registration.core.measurements.pairing`), or ""."""
    n = ev.rejected.get("ambiguous", 0)
    if not n:
        return ""
    return (f"{n} point(s) of {working_topic} and {destination_topic} refused as ambiguous: "
            f"within pair_slop ({ev.settings.pair_slop:g} s) of two points of the other topic; "
            "lower pair_slop below half the measurement period (-p pair_slop:=...)")


def duplicates_line(ev: Evaluation, source: str) -> str:
    """The warning when measurements were rejected as exact duplicates (the accumulator's
    duplicate rule, :mod:`rbc_registration.core.measurements.accumulator`), or ""."""
    n = ev.rejected.get("duplicate", 0)
    if not n:
        return ""
    return (f"{source}: {n} exact duplicate message(s) dropped (the fiducial, stamp and "
            "points of an accepted measurement, or the point and stamp of a point seen before: "
            "a bag recorded twice or a topic republished?); each is one measurement, not a "
            "repeat")


def with_warnings(ev: Evaluation, lines: Sequence[str]) -> Evaluation:
    """``ev`` with ``lines`` added to its warnings and to its report's ``warnings`` (so that
    ``report.json`` and ``report.md`` hold what the command warned about)."""
    warnings = ev.warnings + tuple(lines)
    return ev._replace(warnings=warnings, report={**ev.report, "warnings": list(warnings)})


# -- report directory --------------------------------------------------------------------------
#: Every file :func:`write_report_dir` may write into its directory.
REPORT_FILES = ("report.json", "report.md", "mismatch_histograms.png", "fiducial_map.png",
                "tre_per_target.png", "delta_tre.png", "cv_errors.png")


def write_report_dir(ev: Evaluation, out: Path, title: str = "") -> list[Path]:
    """Write ``report.json`` (metres), ``report.md`` and the PNG figures (millimetres) to ``out``.

    :return: the files written.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    model, rep = ev.model, ev.report
    paths: list[Path] = []
    stages = model.restoration.stages(model.working)[:3]
    values = [pairwise_mismatch(s, model.destination) * MM for s in stages]
    edges = [np.histogram_bin_edges(v, bins=50) for v in values]
    paths.append(figures.mismatch_histograms(out / "mismatch_histograms.png", values, edges,
                                             "Histograms of L (eq. 1)", "mm"))
    tw = ev.targets.working if ev.targets is not None else None
    paths.append(figures.fiducial_map(out / "fiducial_map.png", model.working * MM,
                                      model.corrections * MM, "mm", None if tw is None
                                      else tw * MM, "fiducials and corrections (working frame)"))
    truth = ev.targets.destination if ev.targets is not None else None
    has = with_truth(truth, len(ev.targets.ids) if ev.targets is not None else 0)
    if has.any():
        ids = [t for t, h in zip(ev.targets.ids, has) if h]
        err = target_errors(model, ev.targets.working[has], truth[has])
        paths.append(figures.tre_per_target(out / "tre_per_target.png", ids,
                                            {"TRE_u": err.tre_u * MM, "TRE_c": err.tre_c * MM},
                                            "TRE per target", "mm"))
        paths.append(figures.delta_tre(out / "delta_tre.png", ids, err.delta * MM,
                                       "dTRE = TRE_c - TRE_u", "mm"))
    cv = model.decision.cross_validation.errors
    if cv:
        paths.append(figures.cv_errors(out / "cv_errors.png", {m: e * MM for m, e in cv.items()},
                                       model.decision.method,
                                       "Cross-validated error per candidate", "mm"))
    write_json(rep, out / "report.json")
    paths.append(out / "report.json")
    (out / "report.md").write_text(markdown(ev, [p.name for p in paths if p.suffix == ".png"],
                                            title))
    paths.append(out / "report.md")
    # a directory reused from an earlier report: its figures this one does not make (no truth,
    # no cross-validation) would sit beside it as if they were this bag's
    for name in set(REPORT_FILES) - {p.name for p in paths}:
        stale = out / name
        if stale.is_file() and not stale.is_symlink():
            stale.unlink()
    return paths


def _mm(v: Optional[float], digits: int = 4) -> str:
    return "n/a" if v is None or not math.isfinite(v) else f"{v * MM:.{digits}g}"


def _rho(m: RbcModel) -> str:
    return format_rho(m.rho, m.config.rho_reject, m.config.rho_apply)


def _norm(v: Optional[list]) -> Optional[float]:
    return None if v is None else math.hypot(*v)


def _percent(v: Optional[float]) -> str:
    return "n/a" if v is None else f"{100 * v:.0f}%"


def decision_markdown(decision: dict[str, Any], reason: Optional[str] = None) -> list[str]:
    """The decision of a report (metres) as a Markdown section: mode, method, reason and each
    candidate's cross-validated error in mm.

    :param reason: the reason with its lengths in mm (``Decision.reason_in``); default: the
        report's (metres)."""
    folds = decision["folds"]
    lines = ["## Decision", "",
             f"Mode **{decision['mode']}**: targets get **{decision['method']}** (corrections "
             f"{'applied' if decision['apply'] else 'not applied'}; "
             f"{'confident' if decision['confident'] else 'uncertain'}). "
             f"{md_text(decision['reason'] if reason is None else reason)}",
             "", f"Cross-validated error per candidate ({folds['kind']}, {folds['n_folds']} "
             f"folds; mm):", "",
             "| candidate | median | rms | 95 % bound | Wilcoxon W+ | p-value |",
             "|---|---|---|---|---|---|"]
    for name, c in decision["cv"].items():
        if not c["available"]:
            lines.append(f"| {name} | n/a | n/a | n/a | | {md_text(c['note'])} |")
            continue
        stat = "" if c["statistic"] is None else f"{c['statistic']:.0f}"
        p = "" if c["p_value"] is None else f"{c['p_value']:.2g}"
        lines.append(f"| {name} | {_mm(c['median'])} | {_mm(c['rms'])} | {_mm(c['bound'])} | "
                     f"{stat} | {p} |")
    return lines + [""]


def markdown(ev: Evaluation, images: list[str], title: str = "") -> str:
    """The Markdown report (lengths in mm; ids, paths and topics escaped)."""
    rep, m = ev.report, ev.model
    sl = list(m.sigma_l) + [math.nan] * 3
    bag = rep["bag"]
    lines = [f"# {md_text(title) if title else 'Registration report'}", "",
             f"Bag {md_code(bag['path'])}: " + ", ".join(f"{n} on {md_code(t)}"
                                                  for t, n in bag["messages"].items()) + ".",
             f"{rep['n_fiducials']} fiducials, {rep['n_measurements']} measurements, "
             f"{rep['dim']}D; rejected: " + (", ".join(f"{n} {r}" for r, n in
                                                      bag["rejected"].items() if n) or "none")
             + ". Lengths in mm (report.json: metres).", "",
             *[f"**Warning**: {md_text(w)}" for w in ev.warnings], *([""] if ev.warnings else []),
             *[f"Note: {md_text(note)}" for note in ev.notes], *([""] if ev.notes else []),
             "## Table 1 values", "",
             "| sigma | sigma_axis | sigma_L0 | rho | sigma_L1 | sigma_L2 | rho rule |",
             "|---|---|---|---|---|---|---|",
             f"| {_mm(m.sigma, 3)} ({m.sigma_source}) | {_mm(m.sigma_axis, 3)} | "
             f"{_mm(sl[0], 3)} | {'n/a' if m.rho is None else _rho(m)} | "
             f"{_mm(sl[1], 2)} | {_mm(sl[2], 2)} | {m.recommendation} |", "",
             f"FRE rms: uncorrected {_mm(m.uncorrected.fre_rms)}, corrected "
             f"{_mm(m.corrected.fre_rms)}.", "",
             *decision_markdown(rep["decision"], m.decision.reason_in(MM))]
    if rep["targets"] and "tre_u" in rep["targets"][0]:
        s = rep["summary"]
        n_truth = sum(t["tre_u"] is not None for t in rep["targets"])
        lines += ["## Targets", "",
                  f"Median TRE_u {_mm(s['tre_u_median'])}, TRE_c {_mm(s['tre_c_median'])}; "
                  f"corrections improved {100 * s['fraction_improved']:.0f}% of "
                  f"{n_truth} targets"
                  + (f" with truth ({len(rep['targets']) - n_truth} without: TRE n/a)"
                     if n_truth < len(rep["targets"]) else "") + ".", "",
                  f"The points to use (per the decision): median TRE {_mm(s['tre_median'])}; "
                  f"{_percent(s['fraction_within_bound'])} of targets within their 95 % bound.",
                  "", "| target | TRE | expected TRE | 95 % bound | TRE_u | TRE_c | dTRE "
                  "| inside hull |", "|---|---|---|---|---|---|---|---|"]
        lines += [f"| {md_text(t['id'])} | {_mm(t['tre'])} | {_mm(t['expected_tre'])} | "
                  f"{_mm(t['tre_bound'])} | {_mm(t['tre_u'])} | {_mm(t['tre_c'])} | "
                  f"{_mm(None if t['tre_u'] is None else t['tre_c'] - t['tre_u'], 3)} | "
                  f"{'yes' if t['inside_hull'] else 'no'} |"
                  for t in rep["targets"]]
        lines.append("")
    elif rep["targets"]:
        lines += ["## Targets", "",
                  f"{len(rep['targets'])} targets without truth (TRE not computed): the "
                  f"correction |eps| of each by the {rep['interpolation']} interpolation (applied "
                  "or not as the decision says) and the expected error of the point to use (per "
                  "the decision).", "",
                  f"| target | correction \\|eps\\| ({rep['interpolation']}) | expected TRE | "
                  "95 % bound | inside hull |",
                  "|---|---|---|---|---|"]
        lines += [f"| {md_text(t['id'])} | {_mm(_norm(t['correction']))} | "
                  f"{_mm(t['expected_tre'])} | {_mm(t['tre_bound'])} | "
                  f"{'yes' if t['inside_hull'] else 'no'} |" for t in rep["targets"]]
        lines.append("")
    lines += [f"![{name}]({name})" for name in images]
    return "\n".join(lines + [""])


def print_summary(ev: Evaluation, log: Callable[[str], None] = print) -> None:
    """The text report of ``register`` plus rejections and notes."""
    log(format_report(ev.report))
    rejected = {r: n for r, n in ev.rejected.items() if n}
    if rejected:
        log("  rejected     " + ", ".join(f"{n} {r}" for r, n in rejected.items()))
    for note in ev.notes:
        log(f"  note: {terminal(note)}")
