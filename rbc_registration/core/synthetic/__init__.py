"""Synthetic cells modelled on the paper's experiments, and what is built from them.

- :mod:`.cells`: the A-like, B-like and RA-like cells (``make_cell``).
- :mod:`.structure`: cells with structure: fiducials in groups (a robot's poses) and two
  sessions with a move.
- :mod:`.experiments`: the paper's Table 1 and Figs 2-5.

The names of :mod:`.cells` are importable from this package too
(``from rbc_registration.core.synthetic import make_cell``).
"""

from .. import names_of

__getattr__ = names_of(__name__, "cells")
