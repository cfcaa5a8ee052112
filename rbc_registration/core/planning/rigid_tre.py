"""Rigid-fit part of the target registration error: first-order propagation of anisotropic
fiducial localisation error through the least-squares rigid fit.

Fitzpatrick & West (2001) for isotropic error; anisotropic and per-fiducial error as in Wiles et
al. (2008) and Danilchenko & Fitzpatrick (2011). To first order the fit error moves a working-frame
point x by m(x) = a + L(x - x0) w: translation a, small rotation w, L(c) w = w x c in 3D and
L(c) = (-c_y, c_x) in 2D; i.e. m(x) = D(x) theta with D(x) = [I_d  L(x - x0)] (d x p, p = 3 in
2D, 6 in 3D). The unweighted least-squares fit (as :func:`.registration.rigid_fit`) of fiducial
errors e_j with covariances C_j gives theta = G^-1 sum_j D_j^T e_j, G = sum_j D_j^T D_j, so

    Cov m(T) = D(T) G^-1 S G^-1 D(T)^T,   S = sum_j D_j^T C_j D_j,
    TRE_rigid^2(T) = trace(Cov m(T)).

With C_j = (FLE^2 / 3) I in 3D this is Fitzpatrick & West's TRE^2 = FLE^2 / J (1 + 1/3 sum_k
d_k^2 / f_k^2) (d_k: distance of T from the k-th principal axis of the fiducials, f_k: RMS distance
of the fiducials from it); in 2D, TRE^2 = FLE^2 / J (1 + d^2 / (2 f^2)) with d, f distances from the
centroid. The error is in the working frame; the destination frame is taken as exact. x0 and a
length scale only condition the numbers: the result does not depend on them.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..validation import as_points


def _rotation_block(c: NDArray[np.float64]) -> NDArray[np.float64]:
    """L(c) (N, d, q): the displacement of points c under a small rotation w is L(c) w."""
    if c.shape[1] == 2:
        return np.stack([-c[:, 1], c[:, 0]], axis=1)[:, :, None]
    z = np.zeros(len(c))
    x, y, w = c[:, 0], c[:, 1], c[:, 2]
    # w x c = -[c]x w
    return -np.stack([np.stack([z, -w, y], 1), np.stack([w, z, -x], 1),
                      np.stack([-y, x, z], 1)], axis=1)


class RigidFrame:
    """Origin and scale of the rigid-motion parameters (conditioning only: results are
    independent of them)."""

    def __init__(self, fiducials: NDArray[np.float64]) -> None:
        self.origin = fiducials.mean(axis=0)
        self.scale = float(np.sqrt(np.mean(np.sum((fiducials - self.origin) ** 2, axis=1)))) or 1.0

    def design(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """D(x) (N, d, p): m(x) = D(x) theta."""
        n, d = points.shape
        rot = _rotation_block((points - self.origin) / self.scale)
        return np.concatenate([np.broadcast_to(np.eye(d), (n, d, d)), rot], axis=2)


def _sandwich(design: NDArray[np.float64], cov: NDArray[np.float64]) -> NDArray[np.float64]:
    """sum over rows of D_j^T C_j D_j; ``cov`` (d, d) shared or (N, d, d)."""
    if cov.ndim == 2:
        return np.einsum("nai,ab,nbj->ij", design, cov, design)
    return np.einsum("nai,nab,nbj->ij", design, cov, design)


def rigid_tre_covariance(fiducials: ArrayLike, targets: ArrayLike,
                         fiducial_covariance: ArrayLike) -> NDArray[np.float64]:
    """Covariance (K, d, d) of the rigid-fit error at each target (module docstring, part 2).

    :param fiducials: (J, d) working-frame fiducials the rigid fit uses.
    :param targets: (K, d) working-frame points.
    :param fiducial_covariance: localisation error covariance of the fiducials, (d, d) for all or
        (J, d, d) per fiducial (e.g. Sigma / n_j).
    :return: Cov m(T) per target; its trace is TRE_rigid^2.
    :raises ValueError: on bad shapes, NaN/inf or fiducials that cannot fix a registration.
    """
    x = as_points(fiducials, "fiducials", None, 1)
    t = as_points(targets, "targets", x.shape[1])
    cov = np.asarray(fiducial_covariance, dtype=np.float64)
    d = x.shape[1]
    if cov.shape not in ((d, d), (len(x), d, d)) or not np.all(np.isfinite(cov)):
        raise ValueError(f"fiducial_covariance must be finite with shape ({d}, {d}) or "
                         f"({len(x)}, {d}, {d}), got {cov.shape}")
    frame = RigidFrame(x)
    dx = frame.design(x)
    g_inv = _inverse_normal(np.einsum("nai,naj->ij", dx, dx), "fiducials")
    theta = g_inv @ _sandwich(dx, cov) @ g_inv
    dt = frame.design(t)
    return np.einsum("kai,ij,kbj->kab", dt, theta, dt)


class FitGeometry:
    """How the rigid fit's error grows with where a point is: the factor
    f(T) = sqrt(trace(D(T) G^-1 D(T)^T)), TRE_rigid(T) / FLE for unit isotropic fiducial error
    (module docstring): smallest at the centroid, growing linearly far away.

    :meth:`beyond` is f(T) relative to its largest value at the fiducials, at least 1: how many
    times farther out than every fiducial a target is, in the fit's own measure. An error bound
    calibrated on held-out fiducials holds as far as they reach; beyond, the registration's
    rotation error grows as this factor does.
    """

    def __init__(self, fiducials: ArrayLike) -> None:
        """:param fiducials: (J, d) working-frame fiducials of the fit (near-degenerate ones,
        which :func:`.registration.rigid_fit` accepts, through the pseudo-inverse)."""
        x = as_points(fiducials, "fiducials", None, 1)
        frame = RigidFrame(x)
        dx = frame.design(x)
        g = np.einsum("nai,naj->ij", dx, dx)
        try:
            g_inv = _inverse_normal(g, "fiducials")
        except ValueError:      # a cell thin enough to be near degenerate, which the
            g_inv = np.linalg.pinv(g)   # registration accepted: its poorly fixed rotation shows
        # D(T) is affine in u = (T - origin) / scale, so f^2 = c + b.u + u.H u: its coefficients
        # from f^2 at 0, +-e_i and e_i + e_j (exact up to rounding), a few us per target after
        d = x.shape[1]
        eye = np.eye(d)
        probes = np.vstack([np.zeros((1, d)), eye, -eye] +
                           [eye[i] + eye[j] for i in range(d) for j in range(i + 1, d)])
        dp = frame.design(frame.origin + frame.scale * probes)
        f2 = np.einsum("kai,ij,kaj->k", dp, g_inv, dp)
        c, plus, minus = f2[0], f2[1:1 + d], f2[1 + d:1 + 2 * d]
        b = (plus - minus) / 2
        h = np.diag((plus + minus) / 2 - c)
        pairs = iter(f2[1 + 2 * d:])
        for i in range(d):
            for j in range(i + 1, d):
                h[i, j] = h[j, i] = (next(pairs) - c - b[i] - b[j] - h[i, i] - h[j, j]) / 2
        self._origin, self._inv_scale = frame.origin, 1.0 / frame.scale
        u = (x - self._origin) * self._inv_scale
        r2 = float((c + u @ b + np.einsum("ki,ij,kj->k", u, h, u)).max())
        #: max_j f(X_j), the factor's largest value at the fiducials.
        self.reference = math.sqrt(r2)
        # beyond() in one pass: the coefficients over reference^2
        self._cr, self._br, self._hr = float(c) / r2, b / r2, h / r2

    def beyond(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """max(1, f(T) / max_j f(X_j)) at ``points`` (K, d)."""
        if len(points) == 1:            # ~the node's single target: in floats, not 10 ufuncs
            u = [(p - o) * self._inv_scale for p, o in zip(points[0].tolist(),
                                                            self._origin.tolist())]
            f2 = self._cr + sum(
                ui * (b + sum(h * uj for h, uj in zip(row, u)))
                for ui, b, row in zip(u, self._br.tolist(), self._hr.tolist()))
            return np.array([math.sqrt(max(f2, 1.0))])
        u = points - self._origin
        u *= self._inv_scale
        q = u @ self._hr
        q += self._br
        q *= u
        f2 = q.sum(axis=1)
        f2 += self._cr
        return np.sqrt(np.maximum(f2, 1.0, out=f2), out=f2)


def _inverse_normal(g: NDArray[np.float64], name: str) -> NDArray[np.float64]:
    """G^-1, conditioned on G's diagonal first: a point far from the others (a candidate
    1e9 m out) scales its rotation rows, not its rank."""
    diagonal = np.diag(g)
    if not np.all(diagonal > 0):
        raise ValueError(f"{name} cannot fix a rigid registration (coincident points)")
    s = 1.0 / np.sqrt(diagonal)
    scaled = g * np.outer(s, s)
    if np.linalg.cond(scaled) > 1e12:
        raise ValueError(f"{name} cannot fix a rigid registration (coincident, or collinear "
                         f"in 3D)")
    return np.linalg.inv(scaled) * np.outer(s, s)


class RigidFitError:
    """Rigid-fit part at K points for the current fiducials and after adding each candidate."""

    def __init__(self, fiducials: NDArray[np.float64], fiducial_cov: NDArray[np.float64],
                 candidates: NDArray[np.float64], candidate_cov: NDArray[np.float64],
                 points: NDArray[np.float64]) -> None:
        frame = RigidFrame(fiducials)
        dx = frame.design(fiducials)
        self.g = np.einsum("nai,naj->ij", dx, dx)
        _inverse_normal(self.g, "fiducials")
        self.s = _sandwich(dx, fiducial_cov)
        dc = frame.design(candidates)
        self.gc = np.einsum("cai,caj->cij", dc, dc)
        self.sc = np.einsum("cai,ab,cbj->cij", dc, candidate_cov, dc)
        dp = frame.design(points)
        self.q = np.einsum("kai,kaj->kij", dp, dp)      # trace(D Cov D^T) = sum(Cov * D^T D)

    def now(self) -> NDArray[np.float64]:
        """(K,) TRE_rigid^2 with the current fiducials."""
        g_inv = np.linalg.inv(self.g)
        return np.einsum("ij,kij->k", g_inv @ self.s @ g_inv, self.q)

    def after_each(self, active: NDArray[np.intp]) -> NDArray[np.float64]:
        """(len(active), K) TRE_rigid^2 after adding each candidate ``active`` alone."""
        g_inv = np.linalg.inv(self.g[None] + self.gc[active])
        theta = g_inv @ (self.s[None] + self.sc[active]) @ g_inv
        return theta.reshape(len(theta), -1) @ self.q.reshape(len(self.q), -1).T

    def after_units(self, members: NDArray[np.intp]) -> NDArray[np.float64]:
        """(U, K) TRE_rigid^2 after adding each unit's candidates together: ``members`` (U, m)
        candidate indices per unit, padded with -1 (a robot pose measures several points)."""
        used = (members >= 0)[:, :, None, None]
        at = np.maximum(members, 0)
        g_inv = np.linalg.inv(self.g[None] + np.where(used, self.gc[at], 0.0).sum(axis=1))
        theta = g_inv @ (self.s[None] + np.where(used, self.sc[at], 0.0).sum(axis=1)) @ g_inv
        return theta.reshape(len(theta), -1) @ self.q.reshape(len(self.q), -1).T

    def add(self, c: int) -> None:
        """Condition on candidate ``c`` having been measured."""
        self.g = self.g + self.gc[c]
        self.s = self.s + self.sc[c]
