"""A likely unit mismatch between fiducials and targets (say fiducials in mm, targets in m):
every target outside the fiducials' hull and the targets' scale off by a large factor."""

from __future__ import annotations

from typing import Optional

import numpy as np
from numpy.typing import ArrayLike

#: Every target outside the hull, and the targets' distance from the fiducials' centre (or
#: their spread) this many times the fiducials' size (or this many times smaller): a likely
#: unit mismatch (m vs mm is 1000, m vs cm 100).
UNIT_MISMATCH_FACTOR = 100.0


def _rms_radius(points: np.ndarray, centre: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((points - centre) ** 2, axis=1))))


def unit_mismatch(fiducials: ArrayLike, targets: ArrayLike, inside_hull: ArrayLike
                  ) -> Optional[str]:
    """The warning for targets that look like they are in another unit than the fiducials.

    :param fiducials: fiducial locations (J, d), working frame.
    :param targets: target locations (K, d), working frame.
    :param inside_hull: (K,) the interpolation's inside-hull flags.
    :return: one line naming the likely mismatch and the factor, or ``None``.
    """
    f = np.asarray(fiducials, dtype=float)
    t = np.asarray(targets, dtype=float)
    if len(t) == 0 or len(f) == 0 or np.any(np.asarray(inside_hull, dtype=bool)):
        return None
    centre = f.mean(axis=0)
    size = _rms_radius(f, centre)
    if not size > 0:
        return None
    far = _rms_radius(t, centre) / size
    spread = _rms_radius(t, t.mean(axis=0)) / size if len(t) >= 2 else 0.0
    if far >= UNIT_MISMATCH_FACTOR:
        ratio, how = far, "farther from the fiducials' centre than the fiducials' size"
    elif 0 < spread <= 1 / UNIT_MISMATCH_FACTOR:
        ratio, how = 1 / spread, "smaller in spread than the fiducials"
    else:
        return None
    return (f"all {len(t)} targets are outside the fiducials' hull and ~{ratio:.3g}x {how}: "
            "likely a unit mismatch between targets and fiducials (e.g. m vs mm)")
