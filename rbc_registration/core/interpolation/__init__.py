"""A target's correction from the fiducials' corrections (paper eqs. 5-6).

- :mod:`.paper`: the paper's interpolation (barycentric in the Delaunay simplex, the 2D
  sector rule of :mod:`.sectors` and :mod:`.sector_grid` outside the hull), ``HullTest``.
- :mod:`.kriging`: kriging of the corrections (a Gaussian process); :mod:`.gp_fit`: its fit;
  :mod:`.kriging_summary`: above 2,000 fiducials; :mod:`.blocked_linalg`: its linear algebra
  by blocks.

The names of :mod:`.paper` are importable from this package too
(``from rbc_registration.core.interpolation import PaperInterpolator``).
"""

from .. import names_of

__getattr__ = names_of(__name__, "paper")
