"""Planner variants against the space-filling order on the RA-like cell (issue 13, what was tried).

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/plan_variants.py [--seeds 40]
[--first-seed 0] [--stop 30] [--cell RA] [--json out.json]`` (about 25 s per seed).

The RA-like planner is not at or below the space-filling (``grid``) order at every count
(benchmarks/RESULTS.md, "Planner"). This asks whether another planning rule would be, with the
same set-up as ``plan_cells.py`` (10 random fiducials, then one at a time, the model rebuilt and
its decision made again after every measurement, the actual median target TRE at the decided
point). Every variant keeps the decision-aware first suggestion of the product
(``decisive_candidate`` while the decision is unsure) and changes only how the others are ranked:

- ``planner``: the product (``plan_from_model``: kriging hyper-parameters of the model, the
  expected median TRE at the targets);
- ``oracle``: the same with the hyper-parameters of the model built on all fiducials (not
  available to a user: the best the expected error could be informed);
- ``reml``: hyper-parameters by restricted maximum likelihood: the corrections are the bias with
  its rigid-motion part removed (eq. 4 is blind to rigid motions), so their likelihood is that of
  the projected field; ML on them gives length scales 1.4-1.5x shorter (RA seed 29);
- ``reml mixture``: the expected squared errors averaged over length scales weighted by their
  restricted profile likelihood (hyper-parameter uncertainty);
- ``mean squared``: ranked by the mean expected squared TRE instead of the pooled median;
- ``space-filling ties``: among candidates within 25 % of the best gain, the farthest from the
  fiducials;
- ``space-filling unless 1.5x`` / ``2x``: the space-filling candidate (the farthest from the
  fiducials, the ``grid`` order's next) unless the best candidate is expected to gain at least
  1.5 (2) times as much as it;
- ``rigid projected``: the expected error with the restoration's rigid-motion projection
  (:func:`projected_expected_sq`), every candidate scored exhaustively.

Prints, per variant, the mean over seeds and counts 11..stop of (variant - grid), the counts where
the variant's mean is above grid's with the paired standard error, and the same for random.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import scipy.optimize  # noqa: E402
from scipy.spatial import cKDTree  # noqa: E402
from scipy.spatial.distance import cdist  # noqa: E402

sys.path.insert(0, os.path.dirname(__file__))
from plan_cells import Cell, farthest_point_order  # noqa: E402

from rbc_registration.core.expected_error import (BiasPosterior, ExpectedErrorModel,  # noqa: E402
                                                  RigidFitError, fiducial_covariance,
                                                  pooled_median, target_noise)
from rbc_registration.core.gauss_newton import rigid_motion_basis, rigid_motion_columns  # noqa: E402
from rbc_registration.core.gp_fit import matern52  # noqa: E402
from rbc_registration.core.model_planner import (decisive_candidate,  # noqa: E402
                                                 error_model_from, held_back_by_decision,
                                                 plan_from_model)

VARIANTS = ("planner", "oracle", "reml", "reml mixture", "mean squared", "space-filling ties",
            "space-filling unless 1.5x", "space-filling unless 2x", "rigid projected")


def restricted_nll(x, eps, length, s2, noise2) -> float:
    """-log likelihood of the corrections' components orthogonal to rigid motions."""
    j, d = x.shape
    k = np.kron(s2 * matern52(cdist(x, x), length) + noise2 * np.eye(j), np.eye(d))
    b = rigid_motion_basis(x)
    q = np.linalg.qr(np.hstack([b, np.eye(j * d)]))[0][:, b.shape[1]:j * d]
    c = np.linalg.cholesky(q.T @ k @ q)
    a = np.linalg.solve(c, q.T @ eps.ravel())
    return 0.5 * float(a @ a) + float(np.sum(np.log(np.diag(c))))


def restricted_profile(x, eps, noise2, n_lengths=11):
    """[(weight, length, s)] over length scales from spacing / 2 to 3 x extent, s profiled."""
    spacing = float(np.median(cKDTree(x).query(x, k=2)[0][:, 1]))
    extent = 2.0 * float(np.linalg.norm(x - x.mean(axis=0), axis=1).max())
    rows = []
    for length in np.geomspace(spacing / 2, 3 * extent, n_lengths):
        r = scipy.optimize.minimize_scalar(
            lambda t: restricted_nll(x, eps, length, math.exp(t), noise2), bounds=(-14, 4),
            method="bounded")
        rows.append((r.fun, length, math.sqrt(math.exp(r.x))))
    v = np.array([r[0] for r in rows])
    w = np.exp(-(v - v.min()))
    w /= w.sum()
    return [(float(wi), ln, s) for wi, (_, ln, s) in zip(w, rows) if wi > 0.01 * w.max()]


def expected_after(x, c, pts, components, axis_std) -> np.ndarray:
    """(C, K) expected squared TRE after each candidate, averaged over (weight, l, s)."""
    em0 = ExpectedErrorModel.from_axis_std(components[0][2], components[0][1], axis_std)
    ones = np.ones(len(x))
    rigid = RigidFitError(x, fiducial_covariance(em0, ones), c,
                          fiducial_covariance(em0, np.array([1.0]))[0], pts)
    e = rigid.after_each(np.arange(len(c))) + target_noise(em0, 1.0)
    total = sum(w for w, _, _ in components)
    for w, length, s in components:
        em = ExpectedErrorModel.from_axis_std(s, length, axis_std)
        e = e + w / total * BiasPosterior(x, ones, c, 1.0, pts, em).after_each(np.arange(len(c)))
    return e


def projected_expected_sq(x, pts, s, length, axis_var) -> np.ndarray:
    """(K,) expected squared TRE at ``pts`` of the corrected registration, the restoration's
    rigid-motion projection included (first order, exact in the Gaussian model).

    With z = b + n at the fiducials (bias and noise, (dJ,)), the restoration's corrections are
    eps = -P z (P removes the least-squares rigid motion), the kriged correction at a target
    -W P z, and the correction the target needs -(b_t + n_t) + R_t theta, theta the rigid
    motion fitted to z; so e_t = b_t + n_t - A_t z, A_t = R_t (R^T R)^-1 R^T + W_t P.
    """
    j, d = x.shape
    kk = len(pts)
    centre = x.mean(axis=0)
    kff = s * s * matern52(cdist(x, x), length)
    kfp = s * s * matern52(cdist(x, pts), length)
    w = np.zeros((kk * d, j * d))
    for a in range(d):
        wa = np.linalg.solve(kff + (axis_var[a] + 1e-10 * s * s) * np.eye(j), kfp).T  # (K, J)
        w[a::d, a::d] = wa
    r = rigid_motion_columns(x, centre)
    rt = rigid_motion_columns(pts, centre)
    fit = np.linalg.solve(r.T @ r, r.T)                       # theta = fit @ z
    proj = np.eye(j * d) - r @ fit
    amat = rt @ fit + w @ proj                                # (dK, dJ)
    cz = np.kron(kff, np.eye(d)) + np.kron(np.eye(j), np.diag(axis_var))
    czb = np.kron(kfp, np.eye(d))                             # (dJ, dK)
    per_row = ((amat @ cz) * amat).sum(axis=1) - 2.0 * (amat * czb.T).sum(axis=1)
    per_row = per_row + s * s + np.tile(axis_var, kk)
    return np.maximum(per_row.reshape(kk, d).sum(axis=1), 1e-300)


def next_pick(variant, cell, m, c, em_all) -> int:
    if variant.startswith("space-filling unless"):
        factor = float(variant.split()[-1].rstrip("x"))
        p = plan_from_model(m, c, cell.tw)
        k = int(p.sequence[0])
        if k == int(p.ranking[0]):          # not the decisive first suggestion
            far = int(np.argmax(np.min(np.linalg.norm(c[:, None, :] - m.working[None], axis=2),
                                       axis=1)))
            if p.gains[k] < factor * p.gains[far]:
                k = far
        return k
    if variant in ("planner", "oracle", "space-filling ties"):
        p = plan_from_model(m, c, cell.tw, error_model=em_all if variant == "oracle" else None)
        k = p.sequence[0]
        if variant == "space-filling ties" and k == int(p.ranking[0]):
            ok = np.flatnonzero(p.gains >= 0.75 * p.gains.max())
            far = np.min(np.linalg.norm(c[ok, None, :] - m.working[None], axis=2), axis=1)
            k = int(ok[np.argmax(far)])
        return int(k)
    held = held_back_by_decision(m)
    decisive = decisive_candidate(m, c) if held else None
    if decisive is not None:
        return decisive[0]
    d = cell.dim
    axis_std = np.full(d, cell.sigma / math.sqrt(d))
    if variant == "rigid projected":
        h = m.kriging_hyperparameters
        med = [pooled_median(projected_expected_sq(np.vstack([m.working, c[i:i + 1]]), cell.tw,
                                                   h.signal_std, h.length_scale, axis_std ** 2),
                             d) for i in range(len(c))]
        return int(np.argmin(med))
    if variant == "mean squared":
        h = m.kriging_hyperparameters
        return int(np.argmin(expected_after(m.working, c, cell.tw,
                                            [(1.0, h.length_scale, h.signal_std)],
                                            axis_std).mean(axis=1)))
    comps = restricted_profile(m.working, m.corrections, cell.sigma ** 2 / d)
    if variant == "reml":
        comps = [max(comps)]
    return int(np.argmin(pooled_median(expected_after(m.working, c, cell.tw, comps, axis_std), d)))


def run_seed(name: str, seed: int, stop: int, variants=VARIANTS) -> dict:
    cell = Cell(name, seed)
    n = len(cell.x)
    perm = [int(k) for k in np.random.default_rng([seed, 13]).permutation(n)]
    em_all = error_model_from(cell.model(np.arange(n)))
    out = {}
    for variant in variants:
        chosen, tre = list(perm[:10]), []
        while True:
            m = cell.model(chosen)
            tre.append(cell.tre(m))
            if len(chosen) == stop:
                break
            rest = np.setdiff1d(np.arange(n), chosen)
            chosen.append(int(rest[next_pick(variant, cell, m, cell.x[rest], em_all)]))
        out[variant] = tre
    out["grid"] = [cell.tre(cell.model(farthest_point_order(cell.x, perm[:10], stop - 10)[:j]))
                   for j in range(10, stop + 1)]
    out["random"] = [cell.tre(cell.model(perm[:j])) for j in range(10, stop + 1)]
    return out


def report(runs: list[dict], stop: int) -> list[str]:
    grid = np.array([r["grid"] for r in runs])
    lines = [f"| variant | mean (variant - grid), counts 11-{stop} (mm) | counts above grid "
             "(paired difference ± SE, mm) |", "|---|---|---|"]
    for v in [v for v in VARIANTS if v in runs[0]] + ["random"]:
        diff = np.array([r[v] for r in runs]) - grid
        m, se = diff.mean(axis=0), diff.std(axis=0, ddof=1) / math.sqrt(len(runs))
        above = [f"{10 + i} (+{m[i]:.4f} ± {se[i]:.4f})" for i in range(1, len(m)) if m[i] > 0]
        lines.append(f"| {v} | {m[1:].mean():+.4f} | {len(above)}: {', '.join(above) or '-'} |")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cell", default="RA")
    ap.add_argument("--seeds", type=int, default=40)
    ap.add_argument("--first-seed", type=int, default=0)
    ap.add_argument("--stop", type=int, default=30)
    ap.add_argument("--json", default=None)
    ap.add_argument("--variants", default=",".join(VARIANTS),
                    help="comma-separated, among: " + ", ".join(VARIANTS))
    ap.add_argument("--load", default=None, help="report a --json file instead of running")
    args = ap.parse_args(argv)
    unknown = set(args.variants.split(",")) - set(VARIANTS)
    if unknown:
        ap.error(f"unknown variants {sorted(unknown)}; choose among {', '.join(VARIANTS)}")
    if args.load:
        with open(args.load) as f:
            runs = json.load(f)
    else:
        runs = []
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            runs.append(run_seed(args.cell, seed, args.stop, args.variants.split(",")))
            print(f"seed {seed} done", file=sys.stderr, flush=True)
            if args.json:
                with open(args.json, "w") as f:
                    json.dump(runs, f)
    stop = len(runs[0]["grid"]) + 9
    print(f"{args.cell}-like, {len(runs)} seeds from {args.first_seed}:\n")
    print("\n".join(report(runs, stop)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
