"""Interpolation of fiducial corrections to targets (paper eq. 5-6).

``paper``: 3D, barycentric weights of the Delaunay tetrahedron of fiducials containing the target;
2D, normalised inverse-distance weights of the 8 fiducials surrounding the target (the nearest
fiducial in each 45 degree sector around it, as the 8 neighbours of a hole on a regular grid).

Outside the convex hull of the fiducials the target is flagged (``inside_hull = False``) and the
correction is extrapolated: 3D, inverse-distance weights of the 4 nearest fiducials; 2D, the same
sector rule with the sectors that hold fiducials (the nearest fiducial alone if it coincides).
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import Delaunay, QhullError, cKDTree

from .sector_grid import GRID_MIN_TARGETS, SectorIndex
from .sectors import on_fiducial_tolerance, one_target_weights, sector_weights
from ..validation import as_point_pairs, as_points

#: A simplex whose reciprocal condition number (infinity norm) is below this has no transform
#: (NaN): scipy's limit for its own barycentric transforms, 1000 machine epsilons.
DEGENERATE_RCOND = 1000 * np.finfo(np.float64).eps


class Interpolated(NamedTuple):
    """Interpolated corrections at K targets (same unit as the points).

    :ivar correction: eps(T), shape (K, d), working frame (eq. 5).
    :ivar inside_hull: (K,) whether each target is inside the fiducials' convex hull.
    :ivar expected_error: (K,) 1-sigma uncertainty of eps(T) per axis; NaN when the method gives
        none.
    """

    correction: NDArray[np.float64]
    inside_hull: NDArray[np.bool_]
    expected_error: NDArray[np.float64]


def barycentric_transforms(points: NDArray[np.float64], simplices: NDArray[np.intc]
                           ) -> NDArray[np.float64]:
    """The affine barycentric transforms of triangles (2D) or tetrahedra (3D), as
    ``scipy.spatial.Delaunay.transform`` defines them: ``out[s, :d, :]`` is T^-1 with
    T[i, j] = (r_j - r_d)[i] for the vertices r_0 .. r_d of simplex s, ``out[s, d, :]`` is r_d;
    all NaN where T's reciprocal condition number (infinity norm) is below
    :data:`DEGENERATE_RCOND`.

    The inverse is the adjugate over the determinant, for all simplices at once, in place of
    scipy's LAPACK call per simplex, which the triangulation of every cross-validation fold needs.

    :param points: the triangulated points (J, d), d = 2 or 3.
    :param simplices: vertex indices (S, d + 1).
    :return: (S, d + 1, d), C-contiguous.
    """
    d = points.shape[1]
    c = np.ascontiguousarray(points.T)[:, simplices.T]   # c[i, k]: coordinate i of vertex k, (S,)
    last = c[:, d]
    t = c[:, :d] - last[:, None]                         # t[i, j] = (r_j - r_d)_i
    adj = np.empty_like(t)                               # adjugate: adj[j, i] = cofactor (i, j)
    if d == 2:
        adj[0, 0], adj[1, 1], adj[0, 1], adj[1, 0] = t[1, 1], t[0, 0], -t[0, 1], -t[1, 0]
    elif d == 3:
        for i in range(3):                               # cyclic indices: signs included
            i1, i2 = (i + 1) % 3, (i + 2) % 3
            for j in range(3):
                j1, j2 = (j + 1) % 3, (j + 2) % 3
                adj[j, i] = t[i1, j1] * t[i2, j2] - t[i1, j2] * t[i2, j1]
    else:
        raise ValueError(f"barycentric transforms of {d}D simplices are not implemented")
    det = sum(t[0, j] * adj[j, 0] for j in range(d))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        inv = adj / det
        # one step of iterative refinement, inv += inv (I - T inv): the adjugate alone lost up
        # to 1e-8 (relative) in slivers of condition 1e5-1e6, LU with pivoting 1e-12
        residual = -_products(t, inv)
        residual[range(d), range(d)] += 1.0
        inv += _products(inv, residual)
        norm = np.abs(t).sum(axis=1).max(axis=0) * np.abs(inv).sum(axis=1).max(axis=0)
        degenerate = ~(1.0 / norm >= DEGENERATE_RCOND)   # NaN norms count
    out = np.empty((simplices.shape[0], d + 1, d))
    out[:, :d, :] = inv.transpose(2, 0, 1)
    out[:, d, :] = last.T
    out[degenerate] = np.nan
    return out


def _products(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """The matrix products a[:, :, s] @ b[:, :, s] of (d, d, S) stacks (d = 2, 3), entry by entry
    over contiguous (S,) rows: several times faster than einsum's loop for these tiny matrices."""
    d = len(a)
    out = np.empty_like(a)
    for i in range(d):
        for j in range(d):
            out[i, j] = a[i, 0] * b[0, j]
            for k in range(1, d):
                out[i, j] += a[i, k] * b[k, j]
    return out


class _Triangulation(Delaunay):
    """``scipy.spatial.Delaunay`` with :func:`barycentric_transforms` as its ``transform``, which
    ``find_simplex`` reads; the same numbers to rounding, computed once."""

    @property
    def transform(self) -> NDArray[np.float64]:
        cached = self.__dict__.get("_rbc_transform")
        if cached is None:
            cached = self.__dict__["_rbc_transform"] = barycentric_transforms(
                self.points, self.simplices)
        return cached


class HullTest:
    """Point-in-convex-hull test of the fiducials (Delaunay triangulation).

    Fiducials that span no volume (coplanar in 3D, collinear in 2D) have a flat hull: it is
    triangulated in its own plane (line) and a target is inside only when it lies in that plane.
    """

    #: Relative thickness below which a fiducial set counts as flat.
    FLAT = 1e-6

    def __init__(self, points: NDArray[np.float64]) -> None:
        self.centre = points.mean(axis=0)
        _, s, vt = np.linalg.svd(points - self.centre, full_matrices=False)
        self.flat = bool(s[-1] <= self.FLAT * s[0])
        self.basis = vt[:-1] if self.flat else np.eye(points.shape[1])
        self.tolerance = self.FLAT * float(s[0]) / np.sqrt(len(points))
        local = (points - self.centre) @ self.basis.T
        try:
            if local.shape[1] == 1:
                self.tri = None
                self.interval = (float(local.min()), float(local.max()))
            else:
                # QJ joggles exactly regular grids, whose cospherical points are degenerate; it
                # needs d + 2 points, and d + 1 points are one simplex anyway (default options).
                joggle = "QJ" if len(local) > local.shape[1] + 1 else None
                self.tri = _Triangulation(local, qhull_options=joggle)
                # The barycentric transforms of every simplex, which find_simplex needs: here,
                # with the triangulation (in the node's recompute thread), not in the first
                # answer of a new model (scipy's took 66-111 ms at J = 5,000 in 3D).
                _ = self.tri.transform
        except QhullError as exc:
            raise ValueError(f"fiducials span no area for a convex hull: "
                             f"{str(exc).splitlines()[0]}") from None

    def local(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """Coordinates of points in the frame the hull is triangulated in (a full-dimensional
        hull's basis is the identity: no product, the same numbers)."""
        rel = points - self.centre
        return rel @ self.basis.T if self.flat else rel

    def simplices(self, targets: NDArray[np.float64]) -> NDArray[np.intp]:
        """Index of the simplex containing each target, -1 outside the hull."""
        rel = targets - self.centre
        local = rel @ self.basis.T if self.flat else rel
        if self.tri is None:
            lo, hi = self.interval
            found = np.where((local[:, 0] >= lo) & (local[:, 0] <= hi), 0, -1)
        else:
            found = self.tri.find_simplex(local, tol=1e-9)
        if self.flat:
            off = np.linalg.norm(rel - local @ self.basis, axis=1)
            found = np.where(off <= self.tolerance, found, -1)
        return found


class PaperInterpolator:
    """The paper's interpolation of fiducial corrections (module docstring)."""

    method = "paper"

    def __init__(self, points: ArrayLike, corrections: ArrayLike, *,
                 hull: Optional[HullTest] = None) -> None:
        """:param points: fiducials in the working frame (J, d). :param corrections: eps (J, d).
        :param hull: a :class:`HullTest` of these same points to share (e.g. another
            interpolator's ``hull``); default: built here."""
        self.points, self.corrections = as_point_pairs(points, corrections, min_count=1)
        self.dim = self.points.shape[1]
        if len(self.points) < self.dim + 1:
            raise ValueError(f"interpolation in {self.dim}D needs at least {self.dim + 1} "
                             f"fiducials, got {len(self.points)}")
        self.hull = hull if hull is not None else HullTest(self.points)
        if self.hull.flat:
            shape = "coplanar" if self.dim == 3 else "collinear"
            raise ValueError(f"fiducials are {shape}: the paper's interpolation needs fiducials "
                             f"spanning {'a volume' if self.dim == 3 else 'an area'}; use "
                             f"{'dimension 2 or ' if self.dim == 3 else ''}kriging")
        self.tree = cKDTree(self.points)
        self._on_fiducial = on_fiducial_tolerance(self.points)
        self._sector_index: Optional[SectorIndex] = None
        # 3D: the tetrahedra's vertices as index arrays, converted once.
        self._vertices = self.hull.tri.simplices.astype(np.intp) if self.dim == 3 else None

    def weights(self, targets: ArrayLike) -> tuple[NDArray[np.intp], NDArray[np.float64],
                                                    NDArray[np.bool_]]:
        """Fiducial indices (K, M) and normalised weights (K, M) of eq. 5 for each target.

        Unused slots have weight 0. Also returns the inside-hull flags (K,).
        """
        t = as_points(targets, "targets", self.dim)
        simplex = self.hull.simplices(t)
        return (*self._weights(t, simplex), simplex >= 0)

    def _weights(self, t: NDArray[np.float64], simplex: NDArray[np.intp]
                 ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """:meth:`weights` of validated targets, given their ``hull.simplices``."""
        return self._tetrahedra(t, simplex) if self.dim == 3 else self._sectors(t)

    def __call__(self, targets: ArrayLike) -> Interpolated:
        """Interpolate corrections at targets (K, d) in the working frame."""
        t = as_points(targets, "targets", self.dim)
        return self._at(t, self.hull.simplices(t))

    def _at(self, t: NDArray[np.float64], simplex: NDArray[np.intp]) -> Interpolated:
        """:meth:`__call__` of targets already validated (:func:`.validation.as_points`), given
        their ``hull.simplices`` (one location per call shared by interpolators of one hull)."""
        idx, w = self._weights(t, simplex)
        eps = np.einsum("km,kmd->kd", w, self.corrections[idx])
        return Interpolated(eps, simplex >= 0, np.full(len(eps), np.nan))

    def _idw(self, t: NDArray[np.float64], k: int) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        dist, idx = self.tree.query(t, k=min(k, len(self.points)))
        dist, idx = np.atleast_2d(dist), np.atleast_2d(idx)
        hit = dist[:, :1] <= self._on_fiducial
        w = np.where(hit, (np.arange(idx.shape[1]) == 0).astype(float),
                     1.0 / np.maximum(dist, 1e-300))
        return idx, w / w.sum(axis=1, keepdims=True)

    def _tetrahedra(self, t: NDArray[np.float64], simplex: NDArray[np.intp]
                    ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        inside = simplex >= 0
        if inside.all():                               # no masks: the common single target
            return self._barycentric(t, simplex)
        idx = np.zeros((len(t), 4), dtype=np.intp)
        w = np.zeros((len(t), 4))
        if inside.any():
            idx[inside], w[inside] = self._barycentric(t[inside], simplex[inside])
        idx[~inside], w[~inside] = self._idw(t[~inside], 4)   # fallback outside the hull
        return idx, w

    def _barycentric(self, t: NDArray[np.float64], s: NDArray[np.intp]
                     ) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """Vertices and barycentric coordinates (eq. 5 weights) of targets in tetrahedra ``s``."""
        trans = self.hull.tri.transform[s]
        bary = np.einsum("kij,kj->ki", trans[:, :3, :], self.hull.local(t) - trans[:, 3, :])
        w = np.empty((len(t), 4))
        w[:, :3] = bary
        w[:, 3] = 1.0 - bary.sum(axis=1)
        return self._vertices[s], w

    def _sectors(self, t: NDArray[np.float64]) -> tuple[NDArray[np.intp], NDArray[np.float64]]:
        """The 8-sector rule (:mod:`.sectors`); batches use its grid (:mod:`.sector_grid`),
        built on first use."""
        if len(t) == 1:
            return one_target_weights(self.tree, self.points, t, self._on_fiducial)
        if len(t) < GRID_MIN_TARGETS:
            return sector_weights(self.tree, self.points, t)
        if self._sector_index is None:
            self._sector_index = SectorIndex(self.points, self.tree)
        return self._sector_index.weights(t)
