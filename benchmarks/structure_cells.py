"""Cells with structure: fiducials in groups that share an error, and two sessions with a move.

    .venv/bin/python benchmarks/structure_cells.py [--seeds 20] [--session-seeds 40]
        [--session-cells RA,A] [--json F]

Groups (core/synthetic/structure.make_robot_cell: 36 poses x 3-4 reflectors, one measurement
each, no sigma, 40 targets at poses of their own): per seed the share of targets within their
95 % bound and the mean TRE of the point to use over the mean uncorrected TRE, with the groups
given (leave-one-group-out) and without (leave-one-out by id).

Sessions (moved_sessions of the RA-like and A-like cells, single measurements: 30 % of the
fiducials and every target measured again after a move of 3 sigma per axis plus a rotation of
that size at the cell's RMS radius): the share of seeds whose move is reported, the share of
seeds without a move reported moved, and the median target TRE after re-stationing over that of
the same cell without the move (and, for comparison, with the move mixed in as repeats).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time

import numpy as np

from rbc_registration.core.model import ModelConfig, build_model
from rbc_registration.core.measurements.sessions import estimate_sessions, session_cells
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.core.synthetic.structure import make_robot_cell, moved_sessions


def grouped(seeds: int) -> dict:
    rows = []
    for seed in range(seeds):
        cell = make_robot_cell(seed, targets=40)
        row = {"seed": seed}
        for name, groups in (("groups", cell.fiducial_groups), ("by_id", None)):
            m = build_model(cell.working, cell.destination, ModelConfig(dimension=3),
                            ids=cell.fiducial_ids, groups=groups)
            a = m.answer(cell.target_working)
            tre = np.linalg.norm(a.destination - cell.target_truth, axis=1)
            tre_u = np.linalg.norm(m.uncorrected.apply(cell.target_working)
                                   - cell.target_truth, axis=1)
            row[name] = {"within": float(np.mean(tre <= a.tre_bound)),
                         "ratio": float(tre.mean() / tre_u.mean()),
                         "method": m.decision.method}
        rows.append(row)
        print(f"groups seed {seed}: with groups within {row['groups']['within']:.3f} ratio "
              f"{row['groups']['ratio']:.3f} ({row['groups']['method']}); by id within "
              f"{row['by_id']['within']:.3f} ratio {row['by_id']['ratio']:.3f} "
              f"({row['by_id']['method']})", flush=True)
    return {"rows": rows, **{f"{k}_{q}": float(np.mean([r[k][q] for r in rows]))
                             for k in ("groups", "by_id") for q in ("within", "ratio")}}


def _model_tre(sc, restation: bool, dimension: int) -> tuple[float, bool]:
    labels = sc.sessions if restation else ("s",) * len(sc.sessions)
    tlabels = sc.target_sessions if restation else ("s",) * len(sc.target_sessions)
    plan = estimate_sessions(session_cells(sc.ids, labels, sc.working))
    work, keep = plan.apply(sc.working, labels)
    tw, _ = plan.apply(sc.target_working, tlabels)
    ids = list(dict.fromkeys(np.asarray(sc.ids)[keep]))
    index = {f: k for k, f in enumerate(ids)}
    reps: list[list] = [[] for _ in ids]
    dest = np.zeros((len(ids), dimension))
    for k in np.flatnonzero(keep):
        reps[index[sc.ids[k]]].append(work[k])
        dest[index[sc.ids[k]]] = sc.destination[k]
    m = build_model(np.array([np.mean(r, axis=0) for r in reps]), dest,
                    ModelConfig(dimension=dimension), ids=ids,
                    working_repeats=[np.array(r) for r in reps])
    k = len(sc.target_truth)
    answer = m.answer((tw[:k] + tw[k:]) / 2)
    tre = float(np.median(np.linalg.norm(answer.destination - sc.target_truth, axis=1)))
    return tre, bool(plan.moved)


def sessions(name: str, seeds: int) -> dict:
    rows = []
    for seed in range(seeds):
        cell = make_cell(name, seed, repeats=1)
        d = cell.spec.dimension
        moved = moved_sessions(cell, seed, 3.0)
        still = moved_sessions(cell, seed, 0.0)
        tre_m, found = _model_tre(moved, True, d)
        tre_s, false = _model_tre(still, True, d)
        tre_mixed, _ = _model_tre(moved, False, d)
        rows.append({"seed": seed, "detected": found, "false_move": false,
                     "ratio": tre_m / tre_s, "ratio_mixed": tre_mixed / tre_s})
        print(f"sessions {name} seed {seed}: detected {found}, false {false}, ratio "
              f"{tre_m / tre_s:.3f}, mixed {tre_mixed / tre_s:.3f}", flush=True)
    return {"rows": rows, "detected": float(np.mean([r["detected"] for r in rows])),
            "false_moves": float(np.mean([r["false_move"] for r in rows])),
            "ratio": float(np.mean([r["ratio"] for r in rows])),
            "ratio_mixed": float(np.mean([r["ratio_mixed"] for r in rows]))}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=20, help="grouped cells (default 20)")
    p.add_argument("--session-seeds", type=int, default=40, help="per session cell (40)")
    p.add_argument("--session-cells", default="RA,A",
                   help="session cells, comma-separated (default RA,A)")
    p.add_argument("--json", help="write the results here")
    args = p.parse_args(argv)
    cells = [c for c in args.session_cells.split(",") if c]
    start = time.time()
    out = {"command": " ".join(["benchmarks/structure_cells.py", *(argv or sys.argv[1:])]),
           "machine": platform.platform(), "date": time.strftime("%Y-%m-%d"),
           "groups": grouped(args.seeds) if args.seeds else None,
           "sessions": {c: sessions(c, args.session_seeds) for c in cells}}
    g = out["groups"]
    if g is not None:
        print(f"\ngroups ({args.seeds} seeds): within bound {g['groups_within']:.3f} with "
              f"groups, {g['by_id_within']:.3f} by id; TRE / uncorrected "
              f"{g['groups_ratio']:.3f} with groups, {g['by_id_ratio']:.3f} by id")
    for c, s in out["sessions"].items():
        print(f"sessions {c} ({args.session_seeds} seeds): moves reported {s['detected']:.3f}, "
              f"false moves {s['false_moves']:.3f}, TRE re-stationed / no move "
              f"{s['ratio']:.3f} (mixed in: {s['ratio_mixed']:.3f})")
    print(f"({time.time() - start:.0f} s)")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
