"""Argument types and option groups shared by several subcommands (standard library only)."""

from __future__ import annotations

import argparse
import math
from typing import Callable, Optional

from ..core.constants import DIMENSIONS, INTERPOLATIONS, RESTORATIONS


def positive(text: str) -> float:
    """A finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text!r}")
    return value


def name_list(what: str) -> Callable[[str], tuple[str, ...]]:
    """An argument type: a comma-separated, non-empty list of ``what`` (e.g. fiducial ids)."""
    def parse(text: str) -> tuple[str, ...]:
        names = tuple(s.strip() for s in text.split(",") if s.strip())
        if not names:
            raise argparse.ArgumentTypeError(f"expected a comma-separated list of {what}")
        return names
    return parse


def add_model_options(p: argparse.ArgumentParser, dim_help: str, sigma_help: str,
                      defaults: bool) -> None:
    """``--dim``, ``--sigma``, ``--restoration``, ``--steps``, ``--interpolation``.

    :param defaults: give the core's defaults (``register``); else ``None``, so that the node
        parameters decide (``evaluate``).
    """
    p.add_argument("--dim", type=int, choices=DIMENSIONS, help=dim_help)
    p.add_argument("--sigma", type=float, help=sigma_help)
    p.add_argument("--restoration", choices=RESTORATIONS,
                   default=RESTORATIONS[0] if defaults else None)
    steps: Optional[int] = 2 if defaults else None
    p.add_argument("--steps", type=int, default=steps, help="iterative steps (default 2)")
    p.add_argument("--interpolation", choices=INTERPOLATIONS,
                   default=INTERPOLATIONS[0] if defaults else None)
