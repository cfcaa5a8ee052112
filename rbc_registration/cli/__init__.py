"""The ``rbc-registration`` command: one parser, one module per subcommand (:mod:`.register`,
:mod:`.reproduce`, :mod:`.evaluate`, :mod:`.replay`, :mod:`.synth_bag`, :mod:`.export`,
:mod:`.plan`).

Building the parser imports only the standard library and the numpy-free constants
(:mod:`rbc_registration.core.constants`, :mod:`rbc_registration.io.bag.records`); each
subcommand imports what it needs when it runs, so ``rbc-registration --help`` is instant.
Errors in the input end the command with a one-line message naming what was wrong (exit 2),
never a traceback; a closed stdout (``| head``) ends it quietly (exit 141).
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Optional, Sequence

from ..io.escape import terminal
from ..runtime import default_one_blas_thread
from . import evaluate, export, plan, register, replay, reproduce, synth_bag
from .options import OneLineParser

SUBCOMMANDS = (register, reproduce, evaluate, replay, synth_bag, export, plan)
#: The exit status when stdout's reader closed the pipe early (128 + SIGPIPE).
BROKEN_PIPE_STATUS = 141


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every subcommand."""
    parser = OneLineParser(
        prog="rbc-registration",
        description="Rigid registration from fiducial pairs, improved by restoring the "
                    "rigid-body condition (NISTIR 8180).")
    sub = parser.add_subparsers(dest="command", required=True)
    for module in SUBCOMMANDS:
        module.add_parser(sub)
    return parser


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Entry point of the console script; returns the exit code.

    Defaults BLAS to one thread before any subcommand imports numpy
    (:mod:`rbc_registration.runtime`).
    """
    default_one_blas_thread()
    try:
        try:
            return _run(argv)
        finally:        # what is still buffered meets a closed pipe here, not at exit
            sys.stdout.flush()
    except BrokenPipeError:
        # The reader of stdout is gone (``... | head -3``): end quietly, as Unix tools do.
        # stdout points at devnull so the interpreter's last flush fails no more (Python docs,
        # "Note on SIGPIPE"); 141 = 128 + SIGPIPE, the shell's status of a tool it ended.
        try:
            fd = sys.stdout.fileno()
        except (AttributeError, OSError, ValueError):   # not a file (a test's capture)
            return BROKEN_PIPE_STATUS
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, fd)
        os.close(devnull)
        return BROKEN_PIPE_STATUS


def _run(argv: Optional[Sequence[str]]) -> int:
    """Parse ``argv`` and run its subcommand; bad input ends in one line on stderr (exit 2)."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except BrokenPipeError:                # stdout closed: :func:`main` ends quietly
        raise
    except (ValueError, OSError) as exc:   # bad input: one clear line, no traceback
        print(f"rbc-registration {args.command}: error: {terminal(exc)}", file=sys.stderr)
        return 2
