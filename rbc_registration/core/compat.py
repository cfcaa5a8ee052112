"""What differs between the supported numpy / scipy versions, in one place.

Supported: Ubuntu 24.04's own packages (numpy 1.26, scipy 1.11, matplotlib 3.6), as a ROS 2 Kilted
install from apt uses them, up to the versions pinned in ``constraints.txt``; CI runs the pure
tests with both (``constraints-ubuntu2404.txt``, docs/BUILD.md).
"""

from __future__ import annotations

import inspect
from typing import Any

import scipy.sparse.linalg

#: The relative-tolerance keyword of ``scipy.sparse.linalg.cg``: ``rtol`` since scipy 1.12,
#: ``tol`` before (and removed in 1.14).
CG_RTOL_KEYWORD = "rtol" if "rtol" in inspect.signature(scipy.sparse.linalg.cg).parameters \
    else "tol"


def cg(a: Any, b: Any, *, rtol: float, atol: float, maxiter: int, M: Any = None) -> tuple:
    """``scipy.sparse.linalg.cg`` stopping at ``||r|| <= max(rtol ||b||, atol)`` on every
    supported scipy; returns ``(x, info)`` as scipy does."""
    return scipy.sparse.linalg.cg(a, b, atol=atol, maxiter=maxiter, M=M,
                                  **{CG_RTOL_KEYWORD: rtol})
