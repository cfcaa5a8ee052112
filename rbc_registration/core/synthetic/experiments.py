"""The paper's experiments on synthetic cells: Table 1 and the data of Figs 2-5.

For each cell and interpolation: sigma, sigma_L0..2 and rho (Table 1); TRE per target from the
points as the paper processed them (:attr:`.SyntheticCell.fiducial_processed`: the averaged
measurements of A and B, the single measurements of RA; uncorrected and corrected, Fig. 4 cases
1-2, Fig. 5); and, for cells with
repeats, the median over the N instantaneous datasets of TRE_c^(n) and TRE_u^(n) (Fig. 4 case 3),
each dataset processed on its own (a single measurement of every fiducial and target).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Optional

import numpy as np
from numpy.typing import NDArray

from ..constants import INTERPOLATIONS, DecisionMode
from ..decision.evaluation import TargetErrors, target_errors
from ..rigid.mismatch import pairwise_mismatch
from ..model import ModelConfig, RbcModel, build_model
from ..decision.noise import repeat_stats, sigma_from_stats
from .cells import SyntheticCell


@dataclass(frozen=True)
class InterpolationResult:
    """Results of one interpolation method on one cell (unit of the cell)."""

    averaged: TargetErrors
    instantaneous_tre_u: Optional[NDArray[np.float64]]   # (K,) median over n of TRE_u^(n)
    instantaneous_tre_c: Optional[NDArray[np.float64]]   # (K,) median over n of TRE_c^(n)


@dataclass(frozen=True)
class CellResult:
    """Everything the report, JSON and figures of one cell need."""

    cell: SyntheticCell
    model: RbcModel                                    # fiducial_processed, paper interp.
    mismatch: tuple[NDArray[np.float64], ...]          # L before and after each step (averaged)
    instantaneous_mismatch: Optional[tuple[NDArray[np.float64], ...]]  # (N, bins) per stage
    histogram_edges: tuple[NDArray[np.float64], ...]
    results: dict[str, InterpolationResult]


def _instantaneous(cell: SyntheticCell, config: ModelConfig, sigma: Optional[float],
                   n_sets: int, edges: tuple[NDArray[np.float64], ...],
                   progress: Optional[Callable[[str], None]]):
    k = len(cell.target_ids)
    tre = {m: (np.empty((n_sets, k)), np.empty((n_sets, k))) for m in INTERPOLATIONS}
    counts = [np.empty((n_sets, len(e) - 1), dtype=np.int64) for e in edges]
    for n in range(n_sets):
        x = np.array([m[n] for m in cell.fiducial_measurements])
        t = np.array([m[n] for m in cell.target_measurements])
        for method in INTERPOLATIONS:
            # Many datasets: no decision (mode off), only TRE_u and TRE_c are studied here.
            cfg = replace(config, interpolation=method, sigma=sigma, sigma_axis=None,
                          decision=DecisionMode.OFF)
            model = build_model(x, cell.fiducial_truth, cfg)
            err = target_errors(model, t, cell.target_truth)
            tre[method][0][n], tre[method][1][n] = err.tre_u, err.tre_c
        for s, pts in enumerate(model.restoration.stages(x)):
            counts[s][n] = np.histogram(pairwise_mismatch(pts, cell.fiducial_truth), edges[s])[0]
        if progress and (n + 1) % max(1, n_sets // 10) == 0:
            progress(f"  cell {cell.spec.name}: instantaneous dataset {n + 1}/{n_sets}")
    med = {m: (np.median(u, axis=0), np.median(c, axis=0)) for m, (u, c) in tre.items()}
    return med, tuple(counts)


def run_cell(cell: SyntheticCell, config: Optional[ModelConfig] = None,
             instantaneous_sets: Optional[int] = None, bins: int = 40,
             progress: Optional[Callable[[str], None]] = None) -> CellResult:
    """Run the paper's processing on a synthetic cell.

    :param cell: from :func:`synthetic.make_cell`.
    :param config: restoration settings (dimension is taken from the cell).
    :param instantaneous_sets: how many of the N repeated datasets to process one by one
        (default: all N; none when every point was measured once).
    :param bins: histogram bins of L per stage.
    :param progress: called with a progress line now and then.
    """
    base = config or ModelConfig()
    base = replace(base, dimension=cell.spec.dimension)
    x = cell.fiducial_processed          # A, B: the means; RA: single measurements (the paper)
    y = cell.fiducial_truth
    if cell.spec.sigma_l0_on_means:
        repeats: Optional[tuple[NDArray[np.float64], ...]] = cell.fiducial_measurements
    else:
        # Each fiducial once, as measured; its repeats give sigma only (n_j = 1 for all, or the
        # kriging would take the single measurements of repeated holes as averages).
        repeats = None
        if base.sigma is None and base.sigma_axis is None:
            base = replace(base, sigma=sigma_from_stats(repeat_stats(cell.fiducial_measurements,
                                                                     cell.spec.dimension)))
    results: dict[str, InterpolationResult] = {}
    models = {}
    for method in INTERPOLATIONS:
        cfg = replace(base, interpolation=method)
        models[method] = build_model(x, y, cfg, ids=cell.fiducial_ids, working_repeats=repeats)
    model = models["paper"]
    stages = model.restoration.stages(x)
    mismatch = tuple(pairwise_mismatch(p, y) for p in stages)
    n_min = min(len(m) for m in cell.fiducial_measurements + cell.target_measurements)
    n_sets = 0 if n_min < 2 else min(n_min, instantaneous_sets or n_min)
    edges = []
    inst_counts = None
    inst = None
    if n_sets:
        # Common bin edges per stage, wide enough for the noisy instantaneous datasets.
        probe = np.array([m[0] for m in cell.fiducial_measurements])
        probe_model = build_model(probe, y, replace(base, interpolation="paper",
                                                    decision=DecisionMode.OFF))
        for s, pts in enumerate(probe_model.restoration.stages(probe)):
            lim = 1.5 * max(np.abs(pairwise_mismatch(pts, y)).max(), np.abs(mismatch[s]).max())
            edges.append(np.linspace(-lim, lim, bins + 1))
        inst, inst_counts = _instantaneous(cell, base, model.sigma, n_sets, tuple(edges),
                                           progress)
    else:
        for s in range(len(stages)):
            lim = np.abs(mismatch[s]).max() * 1.05 or 1.0
            edges.append(np.linspace(-lim, lim, bins + 1))
    for method in INTERPOLATIONS:
        averaged = target_errors(models[method], cell.target_means, cell.target_truth)
        u, c = inst[method] if inst else (None, None)
        results[method] = InterpolationResult(averaged, u, c)
    return CellResult(cell, model, mismatch, inst_counts, tuple(edges), results)
