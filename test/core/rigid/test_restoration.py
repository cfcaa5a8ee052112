"""RBC restoration (eq. 4): iterative vs dense vs closed-form, minimum norm, convergence."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbc_registration.core.rigid.mismatch import sigma_l
from rbc_registration.core.rigid.registration import rigid_fit
from rbc_registration.core.rigid.gauss_newton import (dense_gauss_newton_step, gauss_newton_step,
                                                normal_equations, rigid_motion_basis)
from rbc_registration.core.rigid.restoration import closed_form_corrections, restore_rigid_body


def cell(dim=3, j=40, bias=1e-3, seed=0):
    """Destination points, and working points = rigid copy + smooth bias (unit: metres)."""
    rng = np.random.default_rng(seed)
    y = rng.uniform(0, 2, (j, dim))
    r = (Rotation.from_rotvec([0.2, -0.4, 0.9]).as_matrix() if dim == 3
         else np.array([[0.6, -0.8], [0.8, 0.6]]))
    x = (y - 0.5) @ r + bias * np.sin(2 * y[:, ::-1])
    return x, y


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("solver", ["direct", "cg"])
def test_step_equals_dense_formulation(dim, solver):
    x, y = cell(dim, 25)
    np.testing.assert_allclose(gauss_newton_step(x, y, solver), dense_gauss_newton_step(x, y),
                               atol=1e-12, rtol=0)


def test_normal_equations_equal_dense_jacobian_products():
    x, y = cell(3, 9)
    n, rhs = normal_equations(x, y)
    ii, jj = np.triu_indices(9, 1)
    a = np.zeros((len(ii), 27))
    d = x[ii] - x[jj]
    for k in range(3):
        a[np.arange(len(ii)), ii * 3 + k] = 2 * d[:, k]
        a[np.arange(len(ii)), jj * 3 + k] = -2 * d[:, k]
    r = np.sum(d * d, 1) - np.sum((y[ii] - y[jj]) ** 2, 1)
    np.testing.assert_allclose(n, a.T @ a, atol=1e-12)
    np.testing.assert_allclose(rhs, a.T @ r, atol=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
def test_rigid_motions_are_the_null_space(dim):
    x, y = cell(dim, 12)
    n, _ = normal_equations(x - x.mean(0), y)
    q = rigid_motion_basis(x)
    assert q.shape == (12 * dim, 3 if dim == 2 else 6)
    np.testing.assert_allclose(n @ q, 0, atol=1e-10)
    ev = np.linalg.eigvalsh(n)
    assert np.sum(ev < 1e-9 * ev.max()) == q.shape[1]


@pytest.mark.parametrize("dim", [2, 3])
def test_each_step_is_minimum_norm(dim):
    x, y = cell(dim)
    res = restore_rigid_body(x, y)
    for points, eps in zip(res.stages(x), res.step_corrections):
        q = rigid_motion_basis(points)          # no rigid motion in the step at its points
        np.testing.assert_allclose(q.T @ eps.ravel(), 0, atol=1e-14)


@pytest.mark.parametrize("dim", [2, 3])
def test_two_steps_restore_rbc(dim):
    x, y = cell(dim)
    res = restore_rigid_body(x, y, steps=2)
    s0, s1, s2 = res.sigma_l
    assert s1 < 1e-2 * s0 and s2 < 1e-6 * s0
    assert res.sigma_l[-1] == pytest.approx(sigma_l(res.corrected(x), y))
    assert rigid_fit(res.corrected(x), y).fre_rms < 1e-9
    assert len(res.step_corrections) == 2
    np.testing.assert_allclose(sum(res.step_corrections), res.corrections)


def test_steps_are_configurable():
    x, y = cell()
    res = restore_rigid_body(x, y, steps=3)
    assert len(res.sigma_l) == 4 and len(res.stages(x)) == 4


def test_closed_form_is_exact():
    x, y = cell()
    res = restore_rigid_body(x, y, "closed-form")
    assert res.sigma_l[1] < 1e-12
    assert rigid_fit(res.corrected(x), y).fre_rms < 1e-12


@pytest.mark.parametrize("dim", [2, 3])
def test_iterative_and_closed_form_agree_to_second_order(dim):
    diffs = []
    for bias in (1e-3, 1e-4):
        x, y = cell(dim, bias=bias)
        it = restore_rigid_body(x, y).corrections
        cf = closed_form_corrections(x, y)
        assert np.abs(cf).max() == pytest.approx(np.abs(it).max(), rel=0.05)
        diffs.append(np.abs(it - cf).max())
    # a 10x smaller bias gives a ~100x smaller difference: they differ at second order
    assert diffs[1] / diffs[0] < 0.02


def test_coplanar_3d_falls_back_and_still_reduces_mismatch():
    rng = np.random.default_rng(4)
    y = np.c_[rng.uniform(0, 1, (20, 2)), np.zeros(20)]
    x = y + rng.normal(scale=1e-3, size=y.shape)
    res = restore_rigid_body(x, y)
    assert res.sigma_l[2] < 0.01 * res.sigma_l[0]


@pytest.mark.parametrize("kwargs, message", [
    ({"method": "magic"}, "restoration method"), ({"steps": 0}, "steps"),
    ({"steps": 1.5}, "steps"), ({"solver": "lu"}, "solver")])
def test_bad_options(kwargs, message):
    x, y = cell()
    with pytest.raises(ValueError, match=message):
        restore_rigid_body(x, y, **kwargs)


def test_too_few_and_degenerate_fiducials():
    with pytest.raises(ValueError, match="at least 4"):
        restore_rigid_body(np.eye(3), np.eye(3))
    line = np.outer(np.arange(6.0), [1, 0, 0])
    with pytest.raises(ValueError, match="collinear"):
        restore_rigid_body(line, line)
    with pytest.raises(ValueError, match="NaN"):
        restore_rigid_body(np.full((5, 3), np.nan), np.zeros((5, 3)))


def test_sigma_l_is_computed_on_first_access_only():
    """sigma_L0 alone for rho, the other stages when first read, the same values as directly."""
    x, y = cell(3, 30)
    res = restore_rigid_body(x, y)
    assert np.isnan(res.sigma_l_cached).all()            # nothing computed by the restoration
    assert res.sigma_l0 == sigma_l(x, y)
    assert np.isnan(res.sigma_l_cached[1:]).all() and res.sigma_l_cached[0] == res.sigma_l0
    stages = res.stages()
    assert res.sigma_l == tuple(sigma_l(p, y) for p in stages)
    assert res.sigma_l_cached == res.sigma_l
    assert np.isnan(restore_rigid_body(x, y, compute_sigma_l=False).sigma_l).all()


# Six 2D fiducials on a line (0.05 mm noise, mm): CG's first step reported
# success with components off the minimum-norm step, the second then moved a fiducial 173 mm
# (sigma_L 0.037 -> 45 mm, corrected FRE 92 mm), and that was served.
COLLINEAR_WORKING = np.array([[0.0, 1.0], [80.0, 161.0], [160.0, 321.0], [240.0, 481.0],
                              [320.0, 641.0], [400.0, 801.0]])
COLLINEAR_DESTINATION = np.array([
    [99.74479794617777, 200.93855608745923], [128.84545241026063, 377.4755020368713],
    [157.97633730830688, 553.9737180141478], [187.19321845989086, 730.4016385676397],
    [216.19070484773292, 906.9968384089067], [245.42379811002615, 1083.4680439453018]])


def test_a_diverging_cg_step_is_taken_again_by_the_direct_solver():
    auto = restore_rigid_body(COLLINEAR_WORKING, COLLINEAR_DESTINATION)
    direct = restore_rigid_body(COLLINEAR_WORKING, COLLINEAR_DESTINATION, solver="direct")
    # The minimum-norm steps (whether CG diverged here depends on the scipy version: with
    # Ubuntu 24.04's 1.11.4 it did not, and its steps agree with the direct ones to 1e-10 mm).
    np.testing.assert_allclose(auto.corrections, direct.corrections, rtol=0, atol=1e-8)
    assert auto.sigma_l[2] <= auto.sigma_l[1] < 1e-3 * auto.sigma_l[0]
    assert np.abs(auto.corrections).max() < 1.0               # not 173 mm


def test_a_step_that_diverges_with_every_solver_is_refused(monkeypatch):
    import rbc_registration.core.rigid.restoration as restoration
    monkeypatch.setattr(restoration, "gauss_newton_step",
                        lambda x, y, solver: np.full_like(x, 1e3))
    with pytest.raises(ValueError, match=r"^the iterative restoration diverged: a step moved a "
                                         r"fiducial more than 100 x the rigid fit's largest "
                                         r"residual \(0\.07\d+\) with every solver: .*closed-form"):
        restore_rigid_body(COLLINEAR_WORKING, COLLINEAR_DESTINATION)
