"""The rule for a repeated measurement of one fiducial that lies far from its siblings, shared
by the node's accumulator (``outlier_distance``, metres) and the CSV reader of ``register``
(``--outlier-distance``, or a fraction of the fiducial spacing, in the file's unit)."""

from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree


def repeat_outlier(fiducial_id: str, frame: str, point: Sequence[float],
                   earlier_mean: Sequence[float], n_earlier: int, limit: float,
                   limit_name: str = "outlier_distance", kind: str = "fiducial") -> Optional[str]:
    """Whether ``point`` is farther than ``limit`` from the mean of the fiducial's (or target's)
    earlier (accepted) repeats.

    :param frame: ``working`` or ``destination`` (named in the message).
    :param limit: the distance; 0 (or no earlier repeat) switches the check off.
    :param limit_name: how the message names the limit.
    :param kind: what the id names in the message (``fiducial``, ``target``).
    :return: ``None`` when the point is fine, else the message naming the fiducial, the
        distance and the limit.
    """
    if limit <= 0 or n_earlier <= 0:
        return None
    dist = math.dist(point, earlier_mean)
    if dist <= limit:
        return None
    return (f"{kind} {fiducial_id!r}: {frame} point is {dist:.6g} from the mean of its "
            f"{n_earlier} earlier repeat(s), more than {limit_name} {limit:g}")


def typical_spacing(points: ArrayLike) -> float:
    """The median distance from each distinct point to its nearest distinct neighbour.

    Coinciding points (two ids at one place) count once and a few odd points do not move the
    median, so the value depends neither on how ids are laid out nor on a handful of ids.

    :return: 0 when fewer than two distinct points are given.
    """
    unique = np.unique(np.asarray(points, dtype=float), axis=0)
    if len(unique) < 2:
        return 0.0
    dist, _ = cKDTree(unique).query(unique, k=2)
    return float(np.median(dist[:, 1]))
