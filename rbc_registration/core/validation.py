"""Input checks shared by the core modules: every public function validates first and raises a
``ValueError`` (or ``TypeError``) naming what it got."""

from __future__ import annotations

from typing import Optional

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: Points farther than this from the origin are rejected, in any unit (1e12 mm is a million km).
#: The restoration's sums of squared distances and qhull must not overflow or lose the cell: at
#: 1e140 qhull crashed the process, at 1e50-1e90 it called a volume flat, at 1e110 sigma_L was
#: NaN; every number up to 1e12 keeps a cell's spread above rounding.
MAX_ABS_COORDINATE = 1e12


def as_points(points: ArrayLike, name: str = "points", dim: Optional[int] = None,
              min_count: int = 0) -> NDArray[np.float64]:
    """Return ``points`` as a float64 array of shape (N, d), d in {2, 3}, all finite.

    :param points: array-like of shape (N, d).
    :param name: name used in error messages.
    :param dim: required dimension d (2 or 3); ``None`` accepts either.
    :param min_count: minimum number of points N.
    :return: the validated (N, d) float64 array (a copy when a conversion was needed).
    :raises TypeError: when ``points`` is not numeric.
    :raises ValueError: on a wrong shape, too few points, NaN/inf or absurdly large coordinates.
    """
    try:
        arr = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be numeric, got {type(points).__name__}: {exc}") from None
    want = f"(N, {dim})" if dim is not None else "(N, 2) or (N, 3)"
    if arr.ndim != 2 or arr.shape[1] not in (2, 3) or (dim is not None and arr.shape[1] != dim):
        raise ValueError(f"{name} must have shape {want}, got {arr.shape}")
    if arr.shape[0] < min_count:
        raise ValueError(f"{name} needs at least {min_count} points, got {arr.shape[0]}")
    # One pass when all is well: the largest |coordinate| compares False when it is NaN.
    if arr.size and not np.abs(arr).max() <= MAX_ABS_COORDINATE:
        bad = ~np.isfinite(arr)
        if bad.any():
            row = int(np.argwhere(bad)[0][0])
            raise ValueError(f"{name} contains NaN or inf (first at row {row}: "
                             f"{arr[row].tolist()})")
        row = int(np.argmax(np.abs(arr).max(axis=1)))
        raise ValueError(f"{name} has a coordinate beyond ±{MAX_ABS_COORDINATE:g} at row {row}")
    return arr


def as_point_pairs(working: ArrayLike, destination: ArrayLike, dim: Optional[int] = None,
                   min_count: int = 0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Validate two corresponding point sets of equal shape (J, d); see :func:`as_points`."""
    x = as_points(working, "working points", dim, min_count)
    y = as_points(destination, "destination points", x.shape[1], min_count)
    if x.shape != y.shape:
        raise ValueError(f"working and destination points must have the same shape, "
                         f"got {x.shape} and {y.shape}")
    return x, y


#: The spread [the points' unit] below which points are coincident or collinear, wherever the
#: rounding of their coordinates is smaller (per point, in the root-sum-square of the spread).
SPREAD_FLOOR = 1e-9


def check_spread(points: NDArray[np.float64], name: str = "points") -> None:
    """Raise ``ValueError`` when the points cannot fix a rigid registration.

    2D needs two distinct points; 3D needs three points that are not collinear. The spread is
    compared with :data:`SPREAD_FLOOR`, or with the rounding of the coordinates
    (:func:`rounding`) where that is larger: a cell far from its frame's origin (geodetic
    coordinates, 6.4e6 m) keeps the same shapes as one at the origin (a 1e-9 relative
    tolerance called a 2 m x 1 cm rail there collinear).
    """
    d = points.shape[1]
    centred = points - points.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False) if len(points) else np.zeros(1)
    tol = np.sqrt(max(len(points), 1)) * max(SPREAD_FLOOR, rounding(points) if len(points) else 0)
    if s[0] <= tol:
        raise ValueError(f"{name} are coincident: a registration needs distinct points")
    if d == 3 and (len(s) < 2 or s[1] <= tol):
        raise ValueError(f"{name} are collinear: a 3D registration needs 3 non-collinear points")


def check_subset(subset: Optional[object], count: int, name: str) -> NDArray[np.intp]:
    """Return the indices of a subset of ``count`` fiducials (all when ``subset`` is None)."""
    if subset is None:
        return np.arange(count)
    idx = np.asarray(subset)
    if idx.ndim != 1 or idx.size == 0 or not np.issubdtype(idx.dtype, np.integer):
        raise ValueError(f"{name} must be a non-empty list of fiducial indices, got {subset!r}")
    if idx.min() < 0 or idx.max() >= count:
        raise ValueError(f"{name} has an index out of range 0..{count - 1}: {subset!r}")
    if len(np.unique(idx)) != len(idx):
        raise ValueError(f"{name} repeats an index: {subset!r}")
    return idx.astype(np.intp)


#: The rounding of a result relative to the largest coordinate: ~450 x float64's epsilon, for the
#: registrations, restorations and interpolations each computing it. Two methods' held-out errors
#: closer than this times the largest coordinate are equal (exact rigid data: 1e-13 mm
#: differences of pure rounding decided "kriging, p = 0.0036"); it is far below any real
#: difference, also in a frame 5,000 km from its origin (0.5 um).
RESOLUTION = 1e-13


def rounding(*points: ArrayLike) -> float:
    """:data:`RESOLUTION` x the largest coordinate of ``points`` (arrays of points)."""
    return RESOLUTION * max(float(np.abs(np.asarray(p, dtype=np.float64)).max()) for p in points)
