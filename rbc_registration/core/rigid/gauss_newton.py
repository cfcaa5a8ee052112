"""The step of the iterative RBC restoration (:mod:`.restoration`, paper eq. 4): a minimum-norm
Gauss-Newton step on the squared-distance equations linearised at the current points,

    2 D_ij . (eps_i - eps_j) = ||D_ij||^2 - ||E_ij||^2,   D_ij = X_i - X_j, E_ij = Y_i - Y_j.

The normal matrix N = A^T A (dJ x dJ) is assembled from the pair blocks 4 D_ij D_ij^T without ever
forming the J(J-1)/2 x dJ matrix A. Its null space is the infinitesimal rigid motions (translations
and rotations), which are removed explicitly: (N + s Q Q^T) eps = A^T r with Q an orthonormal basis
of the rigid motions gives the minimum-norm solution (Q^T eps = 0). For large J a matrix-free
conjugate-gradient solver applies N in O(J d^2) from moment sums.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg
import scipy.sparse.linalg
from numpy.typing import ArrayLike, NDArray

from .. import compat
from ..validation import as_point_pairs

SOLVERS = ("auto", "direct", "cg")
#: The assembled normal matrix is (dJ)^2 floats: beyond this many fiducials only CG is used.
DIRECT_MAX_FIDUCIALS = 3000


def rigid_motion_columns(points: NDArray[np.float64], centre: NDArray[np.float64]
                         ) -> NDArray[np.float64]:
    """(dJ, m) infinitesimal rigid motions at ``points`` (J, d), not orthonormalised.

    Columns: the d translations (unit length per point), then the rotations about ``centre``
    (one in 2D, three in 3D; displacement omega x (p - centre)). Vectors are flattened row-major
    (x1, y1, ...); m = 3 in 2D, 6 in 3D. Units: translations dimensionless, rotations in the
    points' length unit per radian.
    """
    j, d = points.shape
    c = points - centre
    cols = []
    for k in range(d):
        t = np.zeros((j, d))
        t[:, k] = 1.0
        cols.append(t.ravel())
    if d == 2:
        cols.append(np.column_stack([-c[:, 1], c[:, 0]]).ravel())
    else:
        for k in range(3):
            omega = np.zeros(3)
            omega[k] = 1.0
            cols.append(np.cross(omega, c).ravel())
    return np.column_stack(cols)


def rigid_motion_basis(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Orthonormal basis (dJ, m) of the infinitesimal rigid motions of ``points`` (J, d).

    m = 3 in 2D (2 translations, 1 rotation), 6 in 3D. Vectors are flattened row-major
    (x1, y1, ...).
    """
    q, _ = np.linalg.qr(rigid_motion_columns(points, points.mean(axis=0)))
    return q


def normal_equations(working: NDArray[np.float64], destination: NDArray[np.float64]
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Assemble N = A^T A (dJ, dJ) and A^T r (dJ,) of one Gauss-Newton step from the pair blocks.

    Block (i, j), i != j, of N is -4 D_ij D_ij^T; block (i, i) is 4 sum_j D_ij D_ij^T;
    (A^T r)_i = 2 sum_j D_ij r_ij with r_ij = ||D_ij||^2 - ||E_ij||^2 (linearised eq. 4).
    Built component by component: entry (k, l) of every block is an elementwise J x J product.
    """
    j, d = working.shape
    dx = [working[:, k, None] - working[None, :, k] for k in range(d)]       # D_ij, per axis
    dy = [destination[:, k, None] - destination[None, :, k] for k in range(d)]
    r = sum(a * a for a in dx) - sum(b * b for b in dy)
    rhs = np.empty((j, d))
    n = np.empty((j, d, j, d))
    idx = np.arange(j)
    for k in range(d):
        rhs[:, k] = 2.0 * np.einsum("ij,ij->i", dx[k], r)
        for m in range(k, d):
            block = -4.0 * dx[k] * dx[m]
            block[idx, idx] = -block.sum(axis=1)
            n[:, k, :, m] = block
            if m != k:
                n[:, m, :, k] = block
    return n.reshape(j * d, j * d), rhs.ravel()


def _solve_direct(working: NDArray[np.float64], destination: NDArray[np.float64]
                  ) -> NDArray[np.float64]:
    """Minimum-norm Gauss-Newton step from the assembled normal equations."""
    j, d = working.shape
    n, rhs = normal_equations(working, destination)
    q = rigid_motion_basis(working)
    scale = np.trace(n) / n.shape[0] or 1.0
    m = n + scale * (q @ q.T)
    try:
        eps = scipy.linalg.cho_solve(scipy.linalg.cho_factor(m, lower=True, check_finite=False),
                                     rhs, check_finite=False)
    except np.linalg.LinAlgError:
        # Degenerate geometry (e.g. coplanar 3D fiducials): N has more null vectors than the rigid
        # motions. The pseudo-inverse still gives the minimum-norm step.
        eps = scipy.linalg.pinvh(n, rtol=1e-10) @ rhs
    eps -= q @ (q.T @ eps)
    return eps.reshape(j, d)


def _moments(x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    return x.sum(axis=0), x.T @ x


def _solve_cg(working: NDArray[np.float64], destination: NDArray[np.float64],
              rtol: float = 1e-13) -> NDArray[np.float64]:
    """Matrix-free minimum-norm step: N applied in O(J d^2) from moment sums, block-Jacobi CG.

    With centred points, (N v)_i = 4 sum_j D_ij D_ij^T (v_i - v_j) expands into sums over j of
    x_j, x_j x_j^T, x_j v_j^T and x_j (x_j . v_j); A^T r likewise (see module docstring).
    """
    x, y = working, destination
    j, d = x.shape
    sx, mxx = _moments(x)
    sy, _ = _moments(y)
    xx = np.einsum("ik,ik->i", x, x)

    def matvec(v_flat: NDArray[np.float64]) -> NDArray[np.float64]:
        v = v_flat.reshape(j, d)
        xv = np.einsum("ik,ik->i", x, v)
        sv = v.sum(axis=0)
        c = xv.sum()
        mxv = x.T @ v
        w = x.T @ xv
        su = j * xv - x @ sv - v @ sx + c
        sxu = np.outer(xv, sx) - x @ mxv.T - v @ mxx + w
        return (4.0 * (x * su[:, None] - sxu)).ravel()

    a = xx - np.einsum("ik,ik->i", y, y)
    sr = j * a + a.sum() - 2.0 * x @ sx + 2.0 * y @ sy
    sxr = np.outer(a, sx) + (a @ x)[None, :] - 2.0 * x @ mxx + 2.0 * y @ (x.T @ y).T
    rhs = (2.0 * (x * sr[:, None] - sxr)).ravel()
    # Block-Jacobi preconditioner: diagonal blocks 4 sum_j D_ij D_ij^T.
    diag = 4.0 * (j * x[:, :, None] * x[:, None, :] - x[:, :, None] * sx[None, None, :]
                  - sx[None, :, None] * x[:, None, :] + mxx[None])
    diag += np.eye(d)[None] * (1e-12 * np.trace(mxx) + 1e-300)
    inv = np.linalg.inv(diag)
    pre = scipy.sparse.linalg.LinearOperator(
        (j * d, j * d), matvec=lambda v: np.einsum("ikl,il->ik", inv, v.reshape(j, d)).ravel())
    op = scipy.sparse.linalg.LinearOperator((j * d, j * d), matvec=matvec)
    q = rigid_motion_basis(x)
    rhs -= q @ (q.T @ rhs)

    def project(v: NDArray[np.float64]) -> NDArray[np.float64]:
        return v - q @ (q.T @ v)

    pre_proj = scipy.sparse.linalg.LinearOperator((j * d, j * d),
                                                  matvec=lambda v: project(pre.matvec(project(v))))
    eps, info = compat.cg(op, rhs, rtol=rtol, atol=0.0, maxiter=20 * j * d, M=pre_proj)
    if info > 0:
        raise np.linalg.LinAlgError(f"restoration CG did not converge in {info} iterations")
    if not np.isfinite(eps).all():
        # A breakdown (p^T N p = 0, e.g. collinear 2D fiducials: N has null vectors beyond the
        # rigid motions) gave NaN or inf, and CG reported success.
        raise np.linalg.LinAlgError("restoration CG broke down (NaN in the step)")
    return project(eps).reshape(j, d)


def gauss_newton_step(working: ArrayLike, destination: ArrayLike,
                      solver: str = "auto") -> NDArray[np.float64]:
    """One minimum-norm Gauss-Newton step on the squared-distance equations (linearised eq. 4).

    :param working: current working-frame fiducials (J, d).
    :param destination: destination-frame fiducials (J, d).
    :param solver: ``"direct"`` (normal matrix assembled from the pair blocks, Cholesky),
        ``"cg"`` (the same normal equations applied matrix-free from moment sums, O(J d^2) per
        product) or ``"auto"``: CG, falling back to direct when CG does not converge (degenerate
        geometry such as coplanar 3D fiducials) and J <= :data:`DIRECT_MAX_FIDUCIALS`.
    :return: the step's corrections (J, d), orthogonal to every infinitesimal rigid motion.
    :raises ValueError: on bad input, or when no solver converges.
    """
    x, y = as_point_pairs(working, destination, min_count=2)
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
    # Centre both sets: the equations only involve differences, and centring helps conditioning.
    x = x - x.mean(axis=0)
    y = y - y.mean(axis=0)
    if solver in ("cg", "auto"):
        try:
            return _solve_cg(x, y)
        except np.linalg.LinAlgError as exc:
            if solver == "cg" or len(x) > DIRECT_MAX_FIDUCIALS:
                raise ValueError(f"{exc}: the fiducial geometry is degenerate") from None
    return _solve_direct(x, y)


def dense_gauss_newton_step(working: ArrayLike, destination: ArrayLike) -> NDArray[np.float64]:
    """Reference: the same step from the dense J(J-1)/2 x dJ Jacobian and ``lstsq``.

    For tests and benchmarks only; memory grows as J^3.
    """
    x, y = as_point_pairs(working, destination, min_count=2)
    j, d = x.shape
    ii, jj = np.triu_indices(j, k=1)
    dx = x[ii] - x[jj]
    dy = y[ii] - y[jj]
    a = np.zeros((len(ii), j * d))
    rows = np.arange(len(ii))
    for k in range(d):
        a[rows, ii * d + k] = 2.0 * dx[:, k]
        a[rows, jj * d + k] = -2.0 * dx[:, k]
    r = np.sum(dx * dx, axis=1) - np.sum(dy * dy, axis=1)
    eps, *_ = np.linalg.lstsq(a, r, rcond=None)
    return eps.reshape(j, d)
