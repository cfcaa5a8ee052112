"""Offline evaluation of a recorded cell: a bag's fiducial pairs go through the node's own
ingestion (:class:`~rbc_registration.ros.ingest.Ingest`: stamp pairing, validation, id
assignment, outlier rejection, the shared ``FiducialAccumulator``) and model builder
(:func:`~rbc_registration.ros.worker.build_state`), then the report of ``register``.

No rclpy: nothing here starts a ROS graph. Lengths in metres as in the bag (REP 103); figures and
the Markdown report show millimetres.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Callable, Mapping, NamedTuple, Optional

import numpy as np
from numpy.typing import NDArray

from .core.accumulator import FiducialAccumulator, FiducialSet
from .core.evaluation import leave_one_out, target_errors
from .core.mismatch import pairwise_mismatch
from .core.model import RbcModel
from .core.pairing import StampPairer
from .io import figures
from .io.bag import BagContents, BagError, PairMessage, PointMessage
from .io.report import format_report, model_report, write_json
from .ros.conversions import PairArgs
from .ros.ingest import Ingest
from .ros.params import Settings
from .ros.worker import build_state

MM = 1000.0  # metres -> millimetres for figures and the Markdown report


class Targets(NamedTuple):
    """Targets (metres): ids, working-frame points (K, d), truth (K, d) or ``None``."""

    ids: tuple[str, ...]
    working: NDArray[np.float64]
    destination: Optional[NDArray[np.float64]]
    source: str


class Evaluation(NamedTuple):
    """The outcome of :func:`evaluate_contents`."""

    model: RbcModel
    fiducials: FiducialSet
    settings: Settings
    targets: Optional[Targets]
    report: dict[str, Any]
    rejected: dict[str, int]
    notes: tuple[str, ...]


class _Log:
    """Collects what the node would log (rejections) instead of printing every line."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def warning(self, text: str) -> None:
        self.lines.append(text)

    error = info = warning


def infer_dimension(contents: BagContents) -> tuple[int, str]:
    """2 when every z coordinate of the bag's inputs and targets is exactly 0, else 3.

    :return: the dimension and a sentence saying why.
    """
    zs = []
    for m in contents.inputs + contents.targets:
        if isinstance(m, PointMessage):
            zs.append(m.xyz[2])
        else:
            zs += [m.working[2], m.destination[2]]
    zs = [z for z in zs if not math.isnan(z)]
    if zs and all(z == 0.0 for z in zs):
        return 2, "dimension 2: every z in the bag is 0 (--dim 3 to override)"
    return 3, "dimension 3: the bag has non-zero z (--dim 2 to register x, y only)"


def settings_for(dimension: int, overrides: Mapping[str, Any]) -> Settings:
    """The node's parameters (defaults) with ``dimension`` and ``overrides`` applied.

    :raises ValueError: naming an unknown or invalid parameter.
    """
    return Settings.from_mapping({**overrides, "dimension": dimension})


def accumulate(contents: BagContents, settings: Settings) -> tuple[FiducialSet, dict[str, int],
                                                                   list[str]]:
    """Feed the bag's inputs, in bag order, through the node's ingestion.

    :return: the fiducial set, rejections by reason, and the log lines of the rejections.
    """
    s = settings
    acc = FiducialAccumulator(s.dimension, s.working_frame, s.destination_frame, s.merge_radius,
                              s.outlier_distance)
    log = _Log()
    ingest = Ingest(acc, StampPairer(s.pair_slop, s.point_buffer), None, log)
    for m in contents.inputs:
        if isinstance(m, PairMessage):
            ingest.measurement(PairArgs(m.fiducial_id or None, m.working, m.destination,
                                        m.working_frame, m.destination_frame, m.stamp_s))
        else:
            ingest.point(m.stream, m.xyz, m.frame_id, m.stamp_s)
    return ingest.fiducial_set(), dict(acc.rejected), log.lines


def bag_targets(contents: BagContents, settings: Settings) -> Optional[Targets]:
    """Targets from the bag's targets topic, repeats of an id averaged (first-seen order); truth
    only when every target has a finite destination point.

    :raises BagError: for a target in another frame than the node's.
    """
    if not contents.targets:
        return None
    d = settings.dimension
    groups: dict[str, tuple[list, list]] = {}
    for k, m in enumerate(contents.targets):
        for name, got, want in (("working", m.working_frame, settings.working_frame),
                                ("destination", m.destination_frame, settings.destination_frame)):
            if got and got != want:
                raise BagError(f"target {m.fiducial_id or k!r}: {name} frame {got!r}, expected "
                               f"{want!r}")
        tid = m.fiducial_id or f"target-{k}"
        groups.setdefault(tid, ([], []))
        groups[tid][0].append(m.working[:d])
        groups[tid][1].append(m.destination[:d])
    ids = tuple(groups)
    working = np.array([np.mean(g[0], axis=0) for g in groups.values()])
    if not np.all(np.isfinite(working)):
        raise BagError("a target's working point has NaN or inf")
    truth = np.array([np.mean(g[1], axis=0) for g in groups.values()])
    return Targets(ids, working, truth if np.all(np.isfinite(truth)) else None, "bag")


def evaluate_contents(contents: BagContents, settings: Settings,
                      targets: Optional[Targets] = None, loo: bool = False) -> Evaluation:
    """Accumulate, build the node's model and make the report (lengths in metres).

    :param targets: targets to report (default: the bag's targets topic, if any).
    :raises BagError: when no model can be built (too few fiducials, degenerate geometry).
    """
    fiducials, rejected, log_lines = accumulate(contents, settings)
    state = build_state(fiducials, settings, 0)
    if state.model is None:
        raise BagError(f"{contents.path}: no model: {state.error}"
                       + (f" ({sum(rejected.values())} measurement(s) rejected, e.g. "
                          f"{log_lines[0]})" if log_lines else ""))
    model = state.model
    notes = []
    if targets is None:
        targets = bag_targets(contents, settings)
    if targets is not None and targets.destination is None:
        notes.append("targets have no truth: TRE not computed")
    loo_err = leave_one_out(model) if loo else None
    report = model_report(model, targets.ids if targets else (),
                          targets.working if targets else None,
                          targets.destination if targets else None, loo_err, "m")
    report["bag"] = {"path": str(contents.path), "messages": dict(contents.counts),
                     "rejected": rejected, "disabled": list(fiducials.disabled_ids),
                     "targets_source": targets.source if targets else None,
                     "other_topics": dict(contents.other_topics)}
    return Evaluation(model, fiducials, settings, targets, report, rejected, tuple(notes))


# -- report directory --------------------------------------------------------------------------
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
    err = None
    if ev.targets is not None and ev.targets.destination is not None:
        err = target_errors(model, ev.targets.working, ev.targets.destination)
        paths.append(figures.tre_per_target(out / "tre_per_target.png", ev.targets.ids,
                                            {"TRE_u": err.tre_u * MM, "TRE_c": err.tre_c * MM},
                                            "TRE per target", "mm"))
        paths.append(figures.delta_tre(out / "delta_tre.png", ev.targets.ids, err.delta * MM,
                                       "dTRE = TRE_c - TRE_u", "mm"))
    write_json(rep, out / "report.json")
    paths.append(out / "report.json")
    (out / "report.md").write_text(markdown(ev, [p.name for p in paths if p.suffix == ".png"],
                                            title))
    paths.append(out / "report.md")
    return paths


def _mm(v: Optional[float], digits: int = 4) -> str:
    return "n/a" if v is None or not math.isfinite(v) else f"{v * MM:.{digits}g}"


def markdown(ev: Evaluation, images: list[str], title: str = "") -> str:
    """The Markdown report (lengths in mm)."""
    rep, m = ev.report, ev.model
    sl = list(m.sigma_l) + [math.nan] * 3
    bag = rep["bag"]
    lines = [f"# {title or 'Registration report'}", "",
             f"Bag `{bag['path']}`: " + ", ".join(f"{n} on `{t}`"
                                                  for t, n in bag["messages"].items()) + ".",
             f"{rep['n_fiducials']} fiducials, {rep['n_measurements']} measurements, "
             f"{rep['dim']}D; rejected: " + (", ".join(f"{n} {r}" for r, n in
                                                      bag["rejected"].items() if n) or "none")
             + ". Lengths in mm (report.json: metres).", "",
             "## Table 1 values", "",
             "| sigma | sigma_L0 | rho | sigma_L1 | sigma_L2 | decision |",
             "|---|---|---|---|---|---|",
             f"| {_mm(m.sigma, 3)} ({m.sigma_source}) | {_mm(sl[0], 3)} | "
             f"{'n/a' if m.rho is None else f'{m.rho:.3g}'} | {_mm(sl[1], 2)} | {_mm(sl[2], 2)} "
             f"| **{m.recommendation}** |", "",
             f"FRE rms: uncorrected {_mm(m.uncorrected.fre_rms)}, corrected "
             f"{_mm(m.corrected.fre_rms)}.", ""]
    if rep["targets"] and "tre_u" in rep["targets"][0]:
        s = rep["summary"]
        lines += ["## Targets", "",
                  f"Median TRE_u {_mm(s['tre_u_median'])}, TRE_c {_mm(s['tre_c_median'])}; "
                  f"corrections improved {100 * s['fraction_improved']:.0f}% of "
                  f"{len(rep['targets'])} targets.", "",
                  "| target | TRE_u | TRE_c | dTRE | inside hull |", "|---|---|---|---|---|"]
        lines += [f"| {t['id']} | {_mm(t['tre_u'])} | {_mm(t['tre_c'])} | "
                  f"{_mm(t['tre_c'] - t['tre_u'], 3)} | {'yes' if t['inside_hull'] else 'no'} |"
                  for t in rep["targets"]]
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
        log(f"  note: {note}")
