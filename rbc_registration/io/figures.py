"""Figures of the paper's kind (Figs 2-5), a fiducial map, the decision's cross-validated
errors and a measurement plan, as PNG.

Drawn on :class:`matplotlib.figure.Figure` objects directly (no pyplot, no global backend
selected on import): a figure is rendered to PNG by ``savefig`` alone, so importing this module
changes nothing for an application that uses matplotlib itself.
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from matplotlib.figure import Figure

STAGE_TITLES = ("original", "after step 1", "after step 2", "after step 3")


def mismatch_histograms(path: Path, stages: Sequence[NDArray[np.float64]],
                        edges: Sequence[NDArray[np.float64]], title: str, unit: str,
                        envelopes: Optional[Sequence[NDArray[np.int64]]] = None) -> Path:
    """Histograms of L per restoration stage (Figs 2-3).

    :param stages: L values (averaged fiducials) per stage, filled grey.
    :param edges: bin edges per stage.
    :param envelopes: per stage, (N, bins) counts of the N instantaneous datasets: their lower and
        upper count per bin are drawn as solid and dashed lines (Fig. 2, lines B and C).
    """
    n = len(stages)
    fig = Figure(figsize=(4.2 * n, 3.4))
    axes = fig.subplots(1, n, squeeze=False)
    for s, (ax, vals, e) in enumerate(zip(axes[0], stages, edges)):
        ax.hist(vals, bins=e, color="0.7", label="averaged" if envelopes is not None else "L")
        if envelopes is not None:
            centres = 0.5 * (e[:-1] + e[1:])
            ax.step(centres, envelopes[s].min(axis=0), "k-", where="mid", lw=1,
                    label="instantaneous, min")
            ax.step(centres, envelopes[s].max(axis=0), "k--", where="mid", lw=1,
                    label="instantaneous, max")
        ax.set_title(f"({chr(97 + s)}) {STAGE_TITLES[min(s, 3)]}, sigma_L={np.std(vals):.2g}")
        ax.set_xlabel(f"L [{unit}]")
        ax.ticklabel_format(axis="x", style="sci", scilimits=(-2, 3))
        if s == 0:
            ax.set_ylabel("count")
            ax.legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, path)


def tre_per_target(path: Path, ids: Sequence[str], series: dict[str, ArrayLike], title: str,
                   unit: str) -> Path:
    """TRE per target for several methods (Figs 4 and 5a)."""
    k = np.arange(1, len(ids) + 1)
    fig = Figure(figsize=(max(6.0, 0.12 * len(ids) + 3), 3.6))
    ax = fig.subplots()
    markers = ["o", "s", "^", "v", "D"]
    for (label, values), m in zip(series.items(), markers):
        ax.plot(k, np.asarray(values), m + "-", ms=4, lw=0.8, label=label)
    ax.set_xlabel("target k")
    ax.set_ylabel(f"TRE [{unit}]")
    ax.set_yscale("log")
    ax.set_title(title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, path)


def delta_tre(path: Path, ids: Sequence[str], delta: ArrayLike, title: str, unit: str) -> Path:
    """Delta TRE = TRE_c - TRE_u per target (Fig. 5b); below zero is an improvement."""
    d = np.asarray(delta, dtype=float)
    k = np.arange(1, len(d) + 1)
    fig = Figure(figsize=(max(6.0, 0.12 * len(d) + 3), 3.2))
    ax = fig.subplots()
    ax.bar(k, d, color=np.where(d < 0, "tab:green", "tab:red"))
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xlabel("target k")
    ax.set_ylabel(f"dTRE [{unit}]")
    ax.set_title(f"{title}: improved {np.mean(d < 0) * 100:.0f}% of targets")
    fig.tight_layout()
    return _save(fig, path)


def fiducial_map(path: Path, working: ArrayLike, corrections: ArrayLike, unit: str,
                 targets: Optional[ArrayLike] = None, title: str = "fiducials") -> Path:
    """Fiducials (x, y of the working frame) with their correction arrows, scaled to be visible."""
    x = np.asarray(working, dtype=float)
    eps = np.asarray(corrections, dtype=float)
    span = float(np.ptp(x[:, :2], axis=0).max()) or 1.0
    longest = float(np.linalg.norm(eps[:, :2], axis=1).max()) or 1.0
    scale = 0.08 * span / longest
    fig = Figure(figsize=(6, 5.5))
    ax = fig.subplots()
    ax.plot(x[:, 0], x[:, 1], "k.", ms=4, label="fiducials")
    ax.quiver(x[:, 0], x[:, 1], -eps[:, 0] * scale, -eps[:, 1] * scale, angles="xy",
              scale_units="xy", scale=1, color="tab:blue", width=0.003,
              label=f"-correction x {scale:.3g}")
    if targets is not None and len(targets):
        t = np.asarray(targets, dtype=float)
        ax.plot(t[:, 0], t[:, 1], "r^", ms=5, label="targets")
    ax.set_aspect("equal")
    ax.set_xlabel(f"x [{unit}]")
    ax.set_ylabel(f"y [{unit}]")
    ax.set_title(title)
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    return _save(fig, path)


def cv_errors(path: Path, errors: Mapping[str, ArrayLike], chosen: str, title: str,
              unit: str) -> Path:
    """The cross-validated error of each candidate of the decision: the held-out errors per
    fiducial as a box per candidate (median line, quartile box, whiskers at 1.5 IQR) with every
    fiducial as a dot; the chosen candidate drawn in colour."""
    names = list(errors)
    fig = Figure(figsize=(1.8 * len(names) + 2.5, 3.8))
    ax = fig.subplots()
    values = [np.asarray(errors[n], dtype=float) for n in names]
    box = ax.boxplot(values, patch_artist=True, showfliers=False)
    ax.set_xticks(np.arange(1, len(names) + 1), names)
    rng = np.random.default_rng(0)   # fixed jitter: the same figure for the same data
    for k, (name, v) in enumerate(zip(names, values), start=1):
        colour = "tab:green" if name == chosen else "0.6"
        box["boxes"][k - 1].set_facecolor(colour)
        box["boxes"][k - 1].set_alpha(0.5)
        ax.plot(k + rng.uniform(-0.15, 0.15, len(v)), v, ".", ms=2.5, color="k", alpha=0.5)
        ax.annotate(f"median {np.median(v):.3g}", (k, float(np.max(v))), ha="center",
                    va="bottom", fontsize=7)
    ax.set_ylabel(f"held-out error [{unit}]")
    ax.set_title(f"{title} (chosen: {chosen})")
    fig.tight_layout()
    return _save(fig, path)


def plan_figure(path: Path, fiducials: ArrayLike, candidates: ArrayLike, gains: ArrayLike,
                sequence: Sequence[int], counts: ArrayLike, expected: ArrayLike, unit: str,
                targets: Optional[ArrayLike] = None,
                expected_with_all: Optional[float] = None) -> Path:
    """A measurement plan: (a) the candidates in the working frame (x, y) coloured by their
    expected gain, the fiducials, the targets and the suggested order; (b) the expected median
    target error against the number of fiducials along the suggestions.

    :param gains: (C,) expected gain of each candidate measured next.
    :param sequence: the suggested candidate indices, in order (numbered on the map).
    :param counts, expected: the error curve (fiducial counts and expected median TRE).
    """
    x, c = np.asarray(fiducials, dtype=float), np.asarray(candidates, dtype=float)
    g = np.asarray(gains, dtype=float)
    fig = Figure(figsize=(11, 4.8))
    ax, curve = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.25, 1]})
    dots = ax.scatter(c[:, 0], c[:, 1], c=g, cmap="viridis", s=22, marker="o",
                      label="candidates")
    fig.colorbar(dots, ax=ax, label=f"expected gain [{unit}]")
    ax.plot(x[:, 0], x[:, 1], "kx", ms=6, label="fiducials")
    if targets is not None and len(targets):
        t = np.asarray(targets, dtype=float)
        ax.plot(t[:, 0], t[:, 1], "r^", ms=5, mfc="none", label="targets")
    seq = np.asarray(sequence, dtype=int)
    ax.plot(c[seq, 0], c[seq, 1], "o", ms=10, mfc="none", mec="tab:red", label="suggested")
    for rank, k in enumerate(seq, start=1):
        ax.annotate(str(rank), c[k, :2], xytext=(5, 5), textcoords="offset points",
                    fontsize=8, fontweight="bold", color="tab:red")
    ax.set_aspect("equal")
    ax.set_xlabel(f"x [{unit}] (working frame)")
    ax.set_ylabel(f"y [{unit}]")
    ax.set_title("(a) candidates by expected gain; numbers: suggested order")
    ax.legend(fontsize=7, loc="upper right")
    curve.plot(np.asarray(counts), np.asarray(expected, dtype=float), "o-", ms=4,
               label="expected, suggested order")
    if expected_with_all is not None:
        curve.axhline(expected_with_all, color="0.5", ls="--", lw=1,
                      label="expected, every candidate measured")
    curve.set_xlabel("fiducials")
    curve.set_ylabel(f"expected median target error [{unit}]")
    curve.set_title("(b) expected error against fiducial count")
    curve.legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, path)


def _save(fig: Figure, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path
