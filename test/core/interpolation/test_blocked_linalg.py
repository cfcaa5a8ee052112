"""Dense linear algebra by blocks (core/interpolation/blocked_linalg.py): the numbers of numpy and
scipy."""

import numpy as np
import pytest

from rbc_registration.core.interpolation import blocked_linalg
from rbc_registration.core.interpolation.gp_fit import matern52


def test_blocked_cholesky_and_solve_are_numpy_and_scipy(monkeypatch):
    monkeypatch.setattr(blocked_linalg, "BLOCK", 7)        # several blocks, a partial one
    rng = np.random.default_rng(4)
    x = rng.uniform(0.0, 1.0, (40, 3))
    k = matern52(np.linalg.norm(x[:, None] - x[None], axis=2), 0.3) + 1e-3 * np.eye(40)
    low = blocked_linalg.cholesky_blocked(k.copy())
    np.testing.assert_allclose(low, np.linalg.cholesky(k), rtol=1e-10, atol=1e-12)
    b = rng.normal(size=(40, 5))
    np.testing.assert_allclose(blocked_linalg.solve_blocked(low, b), np.linalg.solve(k, b),
                               rtol=1e-8)
    k[3, 3] = -1.0
    with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
        blocked_linalg.cholesky_blocked(k)


def test_inverse_from_cholesky_is_the_symmetric_inverse():
    rng = np.random.default_rng(5)
    for n in (100, 300, 700):   # one block of rows, and several with a partial one
        x = rng.uniform(0.0, 1.0, (n, 3))
        k = matern52(np.linalg.norm(x[:, None] - x[None], axis=-1), 0.3)
        k.flat[::n + 1] += 1e-3
        factor = np.linalg.cholesky(k)
        factor[np.triu_indices(n, 1)] = rng.normal(size=n * (n - 1) // 2)   # ignored
        inv = blocked_linalg.inverse_from_cholesky(factor)
        np.testing.assert_array_equal(inv, inv.T)
        np.testing.assert_allclose(inv @ k, np.eye(n), atol=1e-8)
        np.testing.assert_allclose(inv, np.linalg.inv(k), rtol=0, atol=1e-10 * np.abs(inv).max())
