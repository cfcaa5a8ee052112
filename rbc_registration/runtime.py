"""Process-wide defaults of the console scripts, applied before numpy is first imported.

One BLAS thread: the node calls BLAS from two threads (services and the recompute thread), and
OpenBLAS's own worker threads spin-wait; on a busy machine they stall the whole node for
seconds. One thread also makes the offline tools compute
exactly what the node computes (kriging's optimiser follows the summation order), so
``evaluate`` on a bag agrees with the live node to the last bit.

OpenBLAS reads ``OPENBLAS_NUM_THREADS`` once, when numpy (or scipy) loads it: setting it later
changes nothing. So :func:`default_one_blas_thread` is called by the entry points
(``rbc-registration`` in :func:`rbc_registration.cli.main`, ``registration_node`` when
:mod:`rbc_registration.ros` is imported, before the node module imports numpy). Set
``OPENBLAS_NUM_THREADS`` (or ``OMP_NUM_THREADS``) yourself to override it. A program that
imports numpy before this package and wants the same sets the variable itself before that.

The objects of a long-running process's start (modules, classes, functions, the node's entities
and replayed journal: about 86,000 in ``registration_node``) live as long as the process: after
start-up :func:`freeze_startup_objects` moves them out of the cyclic garbage collector's reach,
so a full (gen-2) collection, which holds the GIL and so delays every callback, scans only what
came later.
"""

from __future__ import annotations

import gc
import os
import sys


def default_one_blas_thread() -> bool:
    """``OPENBLAS_NUM_THREADS=1`` unless the user set it or ``OMP_NUM_THREADS`` (which OpenBLAS
    would otherwise follow).

    :return: whether it can still take effect, i.e. numpy is not imported yet.
    """
    if "OMP_NUM_THREADS" not in os.environ:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    return "numpy" not in sys.modules


def freeze_startup_objects() -> int:
    """Collect garbage once, then freeze every object tracked now (``gc.freeze``): they are never
    scanned (nor collected) by the cyclic collector again; reference counting still frees them.
    Call once, when a long-running process has started.

    :return: the number of frozen objects.
    """
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()
