"""How often the tilted-plate warning of a 2D reading (core/scale.dropped_z_warning) is given.

Run: ``.venv/bin/python benchmarks/tilt_check.py [--cells 1500] [--seed 2]`` (about 30 s).

Cells of 4 to 300 fiducials in a 500 mm square: flat, with heights (up to 2x the plate's size:
volumes) or with a 120 mm step; the working frame turned about z only (no tilt) with noise
0.01-1 mm and a smooth bias of 0-1 mm; the destination's z measured, or a drawing's 0 (one
cell in five). Prints how many such untilted cells are named (false warnings), then, for
plates tilted 0.5-5 degrees about x (noise 0.05 mm), how many of 40 are named by kind.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from rbc_registration.core.scale import dropped_z_warning


def turn_x(degrees: float) -> np.ndarray:
    a = math.radians(degrees)
    return np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])


def untilted(rng: np.random.Generator, cells: int) -> dict[str, int]:
    """Named cells among ``cells`` untilted ones, by kind (and in all)."""
    named: dict[str, int] = {"all": 0}
    for _ in range(cells):
        j = int(rng.integers(4, 300))
        p = rng.uniform(0, 500, (j, 3))
        p[:, 2] *= rng.choice([0.0, 0.01, 0.05, 0.1, 0.3, 0.5, 1.0, 2.0])
        step = rng.random() < 0.2
        if step:
            p[:, 2] = np.where(p[:, 0] > 250, 120.0, 0.0)
        a = rng.uniform(0, 2 * math.pi)
        turn = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
        noise, bias = rng.choice([0.01, 0.05, 0.2, 1.0]), rng.choice([0.0, 0.1, 0.3, 1.0])
        w = p @ turn.T + [10, 20, 30] + bias * np.column_stack(
            [np.sin(p[:, 0] / 200), np.cos(p[:, 1] / 150), np.sin((p[:, 0] + p[:, 2]) / 180)])
        w += rng.normal(0, noise, w.shape)
        d = p + rng.normal(0, noise * rng.choice([0, 1]), p.shape)
        drawing = rng.random() < 0.2
        if drawing:
            d[:, 2] = 0.0
        if dropped_z_warning(w, d, "mm"):
            kind = ("step" if step else "heights") + (", drawing" if drawing else "")
            named[kind] = named.get(kind, 0) + 1
            named["all"] += 1
    return named


def tilted(rng: np.random.Generator, degrees: float, kind: str, drawing: bool) -> int:
    """Named plates of 40 tilted ``degrees`` about x in the working frame."""
    hits = 0
    for _ in range(40):
        j = int(rng.integers(10, 300))
        p = rng.uniform(0, 500, (j, 3))
        p[:, 2] = {"flat": 0.0, "heights 10 mm": 10.0, "heights 50 mm": 50.0, "step": 0.0}[kind] \
            * rng.uniform(-1, 1, j)
        if kind == "step":
            p[:, 2] = np.where(p[:, 0] > 250, 120.0, 0.0)
        w = p @ turn_x(degrees).T + rng.normal(0, 0.05, (j, 3))
        d = p.copy()
        if drawing:
            d[:, 2] = 0.0
        hits += dropped_z_warning(w, d, "mm") is not None
    return hits


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=int, default=1500)
    ap.add_argument("--seed", type=int, default=2)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    named = untilted(rng, args.cells)
    print(f"untilted cells named: {named['all']} of {args.cells}"
          + "".join(f"; {k}: {v}" for k, v in named.items() if k != "all"))
    kinds = ("flat", "heights 10 mm", "heights 50 mm", "step")
    degrees = (0.5, 1.0, 2.0, 3.0, 5.0)
    print("\n| plate (noise 0.05 mm) | destination z | "
          + " | ".join(f"{g:g} deg" for g in degrees) + " |")
    print("|---|---|" + "---|" * len(degrees))
    for kind in kinds:
        for drawing in (False, True):
            row = [str(tilted(rng, g, kind, drawing)) for g in degrees]
            print(f"| {kind} | {'a drawing 0' if drawing else 'measured'} | "
                  + " | ".join(f"{r}/40" for r in row) + " |")


if __name__ == "__main__":
    main()
