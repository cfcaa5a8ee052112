"""Least-squares rigid registration in 2D and 3D (Arun / Umeyama SVD solution of paper eq. 2)."""

from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..validation import as_point_pairs, check_spread


class Registration(NamedTuple):
    """A rigid transform ``destination ≈ rotation @ working + translation``.

    ``fre_rms`` is the root of paper eq. 2 over the fiducials it was fitted to
    (same unit as the points).
    """

    rotation: NDArray[np.float64]
    translation: NDArray[np.float64]
    fre_rms: float

    def apply(self, points: ArrayLike) -> NDArray[np.float64]:
        """Map working-frame points (N, d) into the destination frame."""
        return np.asarray(points, dtype=np.float64) @ self.rotation.T + self.translation

    def inverse_apply(self, points: ArrayLike) -> NDArray[np.float64]:
        """Map destination-frame points (N, d) back into the working frame."""
        return (np.asarray(points, dtype=np.float64) - self.translation) @ self.rotation


def rigid_fit(working: ArrayLike, destination: ArrayLike,
              weights: Optional[ArrayLike] = None) -> Registration:
    """Fit the proper rigid transform minimising the (weighted) FRE of paper eq. 2.

    :param working: fiducials in the working frame, shape (J, d), d = 2 or 3.
    :param destination: the same fiducials in the destination frame, shape (J, d).
    :param weights: optional non-negative weights, shape (J,), not all zero.
    :return: ``Registration(R, t, fre_rms)`` with ``destination ≈ R @ working + t``;
        ``det(R) = +1`` always (reflections are never returned).
    :raises ValueError: on too few, coincident or (3D) collinear points, NaN/inf, mismatched shapes
        or bad weights.
    """
    x, y = as_point_pairs(working, destination)
    d = x.shape[1]
    if len(x) < d:
        raise ValueError(f"a {d}D registration needs at least {d} fiducials, got {len(x)}")
    if weights is None:
        w = np.ones(len(x))
    else:
        w = np.asarray(weights, dtype=np.float64)
        if w.shape != (len(x),):
            raise ValueError(f"weights must have shape ({len(x)},), got {w.shape}")
        if not np.all(np.isfinite(w)) or (w < 0).any() or w.sum() <= 0:
            raise ValueError("weights must be finite, non-negative and not all zero")
    used = w > 0
    check_spread(x[used], "working points")
    check_spread(y[used], "destination points")
    w = w / w.sum()
    cx = w @ x
    cy = w @ y
    h = (x - cx).T @ ((y - cy) * w[:, None])          # cross-covariance, Arun eq. 11
    u, _, vt = np.linalg.svd(h)
    s = np.eye(d)
    s[-1, -1] = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0  # Umeyama: force det(R) = +1
    r = vt.T @ s @ u.T
    t = cy - r @ cx
    res = x @ r.T + t - y
    fre = float(np.sqrt(np.sum(w * np.sum(res * res, axis=1))))
    return Registration(r, t, fre)


def fre_rms(registration: Registration, working: ArrayLike, destination: ArrayLike) -> float:
    """Root-mean-square fiducial registration error (root of paper eq. 2) of ``registration``."""
    x, y = as_point_pairs(working, destination)
    res = registration.apply(x) - y
    return float(np.sqrt(np.mean(np.sum(res * res, axis=1))))
