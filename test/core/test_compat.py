"""What differs between the supported scipy versions (core/compat.py): cg's tolerance keyword."""

import inspect

import numpy as np
import scipy.sparse.linalg

from rbc_registration.core.compat import CG_RTOL_KEYWORD, cg


def test_the_keyword_is_the_installed_scipy_s():
    assert CG_RTOL_KEYWORD in inspect.signature(scipy.sparse.linalg.cg).parameters


def test_cg_solves_to_the_relative_tolerance():
    rng = np.random.default_rng(0)
    m = rng.normal(size=(30, 30))
    a = m @ m.T + 30 * np.eye(30)
    b = rng.normal(size=30)
    x, info = cg(a, b, rtol=1e-10, atol=0.0, maxiter=500)
    assert info == 0
    assert np.linalg.norm(a @ x - b) <= 1e-10 * np.linalg.norm(b) * 1.0001
