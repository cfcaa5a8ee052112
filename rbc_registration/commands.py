"""Implementations of the ``rbc-registration`` subcommands (argparse namespaces in, exit codes out)."""

from __future__ import annotations

import argparse

import numpy as np

from .core.evaluation import leave_one_out
from .core.model import ModelConfig, build_model
from .io.csv_io import read_fiducials, read_targets
from .io.report import format_report, model_report, write_json


def model_config(args: argparse.Namespace, dimension: int, ids=None) -> ModelConfig:
    """ModelConfig from the shared model options (and fiducial-id subsets)."""
    def indices(subset, name):
        if not subset:
            return None
        missing = [s for s in subset if s not in ids]
        if missing:
            raise ValueError(f"{name}: unknown fiducial id(s) {', '.join(missing)}")
        return tuple(ids.index(s) for s in subset)

    return ModelConfig(dimension=dimension, restoration=args.restoration, steps=args.steps,
                       interpolation=args.interpolation, sigma=args.sigma,
                       uncorrected_subset=indices(getattr(args, "uncorrected_fit", None),
                                                  "--uncorrected-fit"),
                       corrected_subset=indices(getattr(args, "corrected_fit", None),
                                                "--corrected-fit"))


def register(args: argparse.Namespace) -> int:
    """``register``: print the report, write JSON."""
    fid = read_fiducials(args.fiducials, args.dim)
    cfg = model_config(args, fid.dimension, list(fid.ids))
    model = build_model(fid.working, fid.destination, cfg, ids=fid.ids,
                        working_repeats=fid.working_repeats)
    tgt = read_targets(args.targets, fid.dimension) if args.targets else None
    loo = leave_one_out(model) if args.loo else None
    report = model_report(model, tgt.ids if tgt else (), tgt.working if tgt else None,
                          tgt.destination if tgt else None, loo, args.unit)
    print(format_report(report))
    if args.json:
        write_json(report, args.json)
        print(f"wrote {args.json}")
    return 0


def reproduce(args: argparse.Namespace) -> int:
    """``reproduce``: synthetic cells, Table 1, Figs 2-5."""
    from .reproduce import reproduce as run
    cells = tuple(c.strip() for c in args.cells.split(",") if c.strip())
    doc = run(args.out, seed=args.seed, repeats=args.repeats,
              instantaneous_sets=args.instantaneous, cells=cells)
    failed = [f["finding"] for f in doc["findings"] if not f["holds"]]
    return 1 if failed else 0
