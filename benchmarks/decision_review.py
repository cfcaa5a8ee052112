"""The decision on cells the project was not tuned on (an independent review, stop 30).

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/decision_review.py [--seeds 30]``
(~2 min); compare trees with ``PYTHONPATH=<tree>``.

Each cell: fiducials on a jittered grid (2 % of the side) or uniformly at random over a 1 m
square or cube; the working frame a random rigid motion of the truth plus a smooth bias (8 plane
waves of wavelength 1-3 m, scaled to an RMS of ``bias`` x the noise per point) plus Gaussian noise
(RMS 0.1 mm per point over all axes); single measurements, no sigma given, the defaults of
``build_model`` (the ``cv`` decision). 200 targets laid out like the fiducials (a grid of their
own, or random), measured once, the truth known. Per cell over the seeds: how often corrections
were applied, the mean of TRE(destination) / TRE_u (median over the targets), the largest ratio
among the seeds that applied them, the smallest fitted noise against the true one (kriging's
``noise_std`` is all axes, so a sound fit is about 1.4 x the per-axis noise) and the share of
targets within ``tre_bound``.
"""

from __future__ import annotations

import argparse
import math
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from rbc_registration.core.config import ModelConfig  # noqa: E402
from rbc_registration.core.model import build_model  # noqa: E402
from rbc_registration.core.synthetic import random_rotation  # noqa: E402

NOISE = 1e-4        # m, RMS of one measurement over all axes
#: (dimension, layout, fiducials, bias / noise): the review's cells.
CELLS = [(2, "grid", 36, 0.3), (2, "grid", 36, 1.0), (2, "grid", 100, 0.3), (2, "grid", 100, 1.0),
         (3, "grid", 27, 0.3), (3, "grid", 27, 1.0), (3, "grid", 64, 0.3), (3, "grid", 64, 1.0),
         (2, "random", 100, 0.3), (2, "random", 100, 1.0)]


def layout(rng: np.random.Generator, kind: str, n: int, d: int) -> np.ndarray:
    if kind == "grid":
        k = max(2, int(round(n ** (1 / d))))
        p = np.stack(np.meshgrid(*[np.linspace(0, 1, k)] * d, indexing="ij"), -1).reshape(-1, d)
        return p + rng.uniform(-0.02, 0.02, p.shape)
    return rng.uniform(0, 1, (n, d))


def cell(seed: int, d: int, kind: str, n: int, bias: float, targets: int = 200):
    """(working fiducials, destination fiducials, working targets, true targets), metres."""
    rng = np.random.default_rng(seed)
    fid, tgt = layout(rng, kind, n, d), layout(rng, kind, targets, d)
    k = rng.normal(size=(8, d))
    k *= 2 * np.pi / (np.linalg.norm(k, axis=1, keepdims=True) * rng.uniform(1, 3, (8, 1)))
    phase, amp = rng.uniform(0, 2 * np.pi, 8), rng.normal(size=(8, d))

    def field(p: np.ndarray) -> np.ndarray:
        return np.sin(p @ k.T + phase) @ amp

    scale = bias * NOISE / np.sqrt(np.mean(np.sum(field(fid) ** 2, axis=1)))
    r, t = random_rotation(rng, d), rng.uniform(-1, 1, d)

    def work(p: np.ndarray) -> np.ndarray:
        return (p - t) @ r + scale * field(p) + rng.normal(0, NOISE / math.sqrt(d), p.shape)

    return work(fid), fid, work(tgt), tgt


def row(d: int, kind: str, n: int, bias: float, seeds: int) -> str:
    ratios, applied, noise, within = [], [], [], []
    for s in range(seeds):
        x, y, tw, tt = cell(s, d, kind, n, bias)
        model = build_model(x, y, ModelConfig(dimension=d))
        ans = model.answer(tw)
        err = np.linalg.norm(ans.destination - tt, axis=1)
        ratio = float(np.median(err) / np.median(np.linalg.norm(model.uncorrected.apply(tw) - tt,
                                                                 axis=1)))
        ratios.append(ratio)
        within.append(err <= ans.tre_bound)
        if model.decision.apply:
            applied.append(ratio)
            if model.decision.method == "kriging":
                noise.append(model.kriging_hyperparameters.noise_std / (NOISE / math.sqrt(d)))
    worst = f"{max(applied):.3f}" if applied else "-"
    low = f"{min(noise):.2g}" if noise else "-"
    return (f"| {d}D {kind} | {n} | {bias:g} | {len(applied)}/{seeds} | {np.mean(ratios):.3f} | "
            f"{worst} | {low} | {100 * np.mean(np.concatenate(within)):.1f} % |")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=30)
    args = p.parse_args()
    print("| cell | J | bias / noise | applied | mean ratio | worst ratio applied | smallest "
          "fitted / true noise (kriging applied) | within tre_bound |")
    print("|---|---|---|---|---|---|---|---|")
    for spec in CELLS:
        print(row(*spec, args.seeds), flush=True)


if __name__ == "__main__":
    main()
