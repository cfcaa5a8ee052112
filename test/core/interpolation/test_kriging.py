"""The fast kriging fit: analytic gradient, warm start, subsample rule, exact held-out values."""

import math

import numpy as np
import pytest
import scipy.optimize
from scipy.spatial.transform import Rotation

from rbc_registration.core.interpolation import gp_fit
from rbc_registration.core.interpolation.gp_fit import (KrigingHyperparameters, MarginalLikelihood,
                                          fit_hyperparameters)
from rbc_registration.core.interpolation.kriging import KrigingInterpolator


def field_cell(seed=0, j=80, d=3, noise=2e-3):
    rng = np.random.default_rng(seed)
    x = rng.uniform(0, 3, (j, d))
    eps = 0.01 * np.sin(1.3 * x + rng.uniform(0, 6, d)) + rng.normal(scale=noise, size=x.shape)
    return x, eps


@pytest.mark.parametrize("noise2", [None, 4e-6], ids=["noise-fitted", "noise-given"])
@pytest.mark.parametrize("d", [2, 3])
def test_analytic_gradient_matches_finite_differences(noise2, d):
    x, eps = field_cell(1, 50, d)
    counts = np.random.default_rng(2).integers(1, 5, len(x)).astype(float)   # n_j repeats
    nll = MarginalLikelihood(x, eps, 1.0 / counts, float(np.mean(eps ** 2)), noise2)
    for theta in ([0.3, 0.2, -3.0], [-1.0, 1.5, -6.0], [2.0, -0.5, 0.5]):
        theta = np.array(theta[:3 if noise2 is None else 2])
        value, grad = nll(theta)
        numeric = scipy.optimize.approx_fprime(theta, lambda t: nll(t)[0], 1e-6)
        np.testing.assert_allclose(grad, numeric, rtol=1e-4, atol=1e-4 * abs(value))


def test_the_likelihood_is_the_gaussian_log_density():
    x, eps = field_cell(3, 30, 2)
    nll = MarginalLikelihood(x, eps, np.ones(30), 1.0)
    s2, length, noise2 = nll.unpack([math.log(2e-4), math.log(1.1), math.log(3e-6)])
    r = np.linalg.norm(x[:, None] - x[None], axis=2)
    a = math.sqrt(5) * r / length
    k = s2 * (1 + a + a * a / 3) * np.exp(-a) + np.eye(30) * (noise2 + gp_fit.JITTER * s2)
    want = sum(0.5 * e @ np.linalg.solve(k, e) + 0.5 * np.linalg.slogdet(k)[1] for e in eps.T)
    assert nll(np.log([2e-4, 1.1, 3e-6]))[0] == pytest.approx(want, rel=1e-9)


def test_fit_finds_the_noise_and_the_warm_start_the_same_optimum():
    x, eps = field_cell(4, 120, 3)
    cold = fit_hyperparameters(x, eps)
    assert cold.noise_fitted and cold.noise_std == pytest.approx(2e-3 * math.sqrt(3), rel=0.3)
    near = cold._replace(length_scale=cold.length_scale * 1.5, signal_std=cold.signal_std * 0.7)
    warm = fit_hyperparameters(x, eps, initial=near)
    for a, b in zip(warm[:3], cold[:3]):
        assert a == pytest.approx(b, rel=1e-3)
    # a misleading warm start (pure-noise optimum) is not reused blindly
    bad = KrigingHyperparameters(1e-6, 1e-3, 1.0, True)
    again = fit_hyperparameters(x, eps, initial=bad)
    assert again.length_scale == pytest.approx(cold.length_scale, rel=1e-3)


def test_a_warm_start_above_the_fit_subsample_is_refined_there_from_where_it_was(monkeypatch):
    """Above FIT_MAX_FIDUCIALS (the search on a smaller subsample): a warm start in the best basin
    is refined on the fit's subsample from itself, not from the search's optimum; the same
    optimum, in a few evaluations there when it is the optimum already."""
    monkeypatch.setattr(gp_fit, "FIT_MAX_FIDUCIALS", 160)
    monkeypatch.setattr(gp_fit, "SEARCH_MAX_FIDUCIALS", 60)
    x, eps = field_cell(5, 400, 3)
    on_fit = []
    real = MarginalLikelihood.__call__

    def counted(self, theta):
        if len(self.eps) == 160:
            on_fit.append(1)
        return real(self, theta)
    monkeypatch.setattr(MarginalLikelihood, "__call__", counted)
    cold = fit_hyperparameters(x, eps)
    n_cold = len(on_fit)
    on_fit.clear()
    warm = fit_hyperparameters(x, eps, initial=cold)
    assert len(on_fit) <= 3 < n_cold
    near = fit_hyperparameters(x, eps, initial=cold._replace(
        length_scale=cold.length_scale * 1.3, signal_std=cold.signal_std * 0.8))
    for other in (warm, near):
        for a, b in zip(other[:3], cold[:3]):
            assert a == pytest.approx(b, rel=1e-3)


def test_given_sigma_is_kept_and_warm_start_is_used_by_the_interpolator():
    x, eps = field_cell(5, 60, 2)
    ip = KrigingInterpolator(x, eps, sigma=0.003)
    assert ip.hyper.noise_std == 0.003 and not ip.hyper.noise_fitted
    warm = KrigingInterpolator(x, eps, sigma=0.003, warm_start=ip.hyper)
    assert warm.hyper.length_scale == pytest.approx(ip.hyper.length_scale, rel=1e-3)
    assert ip.noise_axis_std == pytest.approx(0.003 / math.sqrt(2))


def test_subsample_rule_is_spread_and_invariant():
    rng = np.random.default_rng(6)
    x = rng.uniform(0, 10, (3000, 3))
    idx = gp_fit._subsample(x, 500)
    assert len(idx) == 500 and len(np.unique(idx)) == 500
    perm = rng.permutation(len(x))
    np.testing.assert_array_equal(np.sort(perm[gp_fit._subsample(x[perm], 500)]), idx)
    rot = Rotation.from_rotvec([0.3, -1.0, 2.0]).as_matrix()
    np.testing.assert_array_equal(gp_fit._subsample(x @ rot.T + 7.0, 500), idx)
    np.testing.assert_array_equal(gp_fit._subsample(x[:100], 500), np.arange(100))
    # it spans the cell, not one corner
    assert np.ptp(x[idx], axis=0).min() > 9.0


def test_large_sets_fit_on_a_subsample(monkeypatch):
    x, eps = field_cell(7, 400, 3)
    full = fit_hyperparameters(x, eps)
    monkeypatch.setattr(gp_fit, "FIT_MAX_FIDUCIALS", 200)
    monkeypatch.setattr(gp_fit, "SEARCH_MAX_FIDUCIALS", 100)
    sub = fit_hyperparameters(x, eps)
    assert sub.length_scale == pytest.approx(full.length_scale, rel=0.3)
    assert sub.noise_std == pytest.approx(full.noise_std, rel=0.3)


def test_held_out_is_the_gp_refitted_without_the_group():
    x, eps = field_cell(8, 40, 3)
    counts = np.arange(40) % 3 + 1
    ip = KrigingInterpolator(x, eps, repeats=counts)
    groups = [np.array([5]), np.array([0, 17, 33])]
    for s, (w, std) in zip(groups, ip.held_out(groups)):
        keep = np.setdiff1d(np.arange(40), s)
        sub = KrigingInterpolator(x[keep], eps[keep], repeats=counts[keep],
                                  hyperparameters=ip.hyper)
        res = sub(x[s])
        np.testing.assert_allclose(w @ eps[keep], res.correction, rtol=1e-7, atol=1e-12)
        noise = ip.hyper.noise_std ** 2 / 3 / counts[s]
        np.testing.assert_allclose(std, np.sqrt(res.expected_error ** 2 + noise), rtol=1e-6)


def test_fit_validation():
    x, eps = field_cell(9, 20, 2)
    with pytest.raises(ValueError, match="repeats must be 20 counts"):
        fit_hyperparameters(x, eps, repeats=np.zeros(20))
    with pytest.raises(ValueError, match="sigma must be finite"):
        fit_hyperparameters(x, eps, sigma=math.inf)
    with pytest.raises(ValueError, match="same shape"):
        fit_hyperparameters(x, eps[:10])


def test_batches_are_taken_in_chunks_with_the_same_answer(monkeypatch):
    """A batch of targets is answered chunk by chunk (memory O(J) per chunk): the mean and the
    expected error are those of one pass (to BLAS rounding), for chunks of 1, 7 and all
    targets."""
    from rbc_registration.core.interpolation import kriging

    rng = np.random.default_rng(3)
    x = rng.uniform(0.0, 1.0, (60, 3))
    k = KrigingInterpolator(x, 1e-4 * np.sin(3.0 * x) + rng.normal(0.0, 1e-5, x.shape),
                            sigma=1e-5)
    targets = rng.uniform(-0.1, 1.1, (50, 3))
    whole = k(targets)
    for chunk_targets in (1, 7):
        monkeypatch.setattr(kriging, "CHUNK_ELEMENTS", chunk_targets * len(x))
        part = k(targets)
        np.testing.assert_allclose(part.correction, whole.correction, rtol=1e-12, atol=1e-20)
        np.testing.assert_allclose(part.expected_error, whole.expected_error, rtol=1e-12)
        np.testing.assert_array_equal(part.inside_hull, whole.inside_hull)


def test_matern52_in_blocks_is_the_closed_form(monkeypatch):
    """matern52 works block by block in place: the closed form (1 + a + a^2/3) exp(-a),
    a = sqrt(5) r / l, across block boundaries, for an empty, a strided and a C array."""
    rng = np.random.default_rng(4)
    monkeypatch.setattr(gp_fit, "_BLOCK_ELEMENTS", 7)
    for r in (rng.uniform(0.0, 3.0, (13, 11)), rng.uniform(0.0, 3.0, (20, 9))[::2, 1:],
              np.zeros((0, 4))):
        a = math.sqrt(5.0) * r / 0.8
        expected = (1.0 + a + a * a / 3.0) * np.exp(-a)
        got = gp_fit.matern52(r.copy(), 0.8)
        assert got.shape == r.shape
        np.testing.assert_allclose(got, expected, rtol=1e-14, atol=0.0)


def test_exact_rigid_data_on_few_fiducials_fits_without_numpy_warnings():
    """4 fiducials of exact rigid data (corrections 0): the fit's K^-1 of a near-singular factor
    was NaN and numpy warned on stderr ("invalid value encountered in matmul") in `register`."""
    import warnings
    from rbc_registration.core.model import ModelConfig, build_model
    x = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model = build_model(x, x.copy(), ModelConfig(dimension=3))
    assert model.decision.method == "uncorrected"


def test_more_fiducials_than_kriging_holds_are_one_clear_refusal(monkeypatch):
    """100,000 fiducials ended in a MemoryError traceback (a 74.5 GiB covariance); above
    MAX_FIDUCIALS kriging is refused, and the decision goes on without it."""
    import rbc_registration.core.interpolation.kriging as kriging
    from rbc_registration.core.model import ModelConfig, build_model
    monkeypatch.setattr(kriging, "MAX_FIDUCIALS", 20)
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 1, (21, 3))
    y = x + 0.01 * np.sin(3 * x) + rng.normal(0, 1e-4, x.shape)
    with pytest.raises(ValueError, match=r"^kriging holds a J x J covariance: 21 fiducials "
                                         r"would need .* GB for it, at most 20 are kriged"):
        KrigingInterpolator(x, y - x)
    model = build_model(x, y, ModelConfig(dimension=3))            # cv: paper or uncorrected
    assert "kriging" in model.decision.cross_validation.unavailable
    assert model.decision.method != "kriging"
    with pytest.raises(ValueError, match="at most 20 are kriged"):
        build_model(x, y, ModelConfig(dimension=3, interpolation="kriging"))


def _weak_bias_grid(seed, noise=1e-4, bias=0.3e-4):
    """A cell: a jittered 6 x 6 grid over 1 m, a smooth bias 0.3 x the noise, single
    measurements (noise RMS over both axes)."""
    rng = np.random.default_rng(seed)
    g = np.linspace(0, 1, 6)
    y = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    y = y + rng.uniform(-0.02, 0.02, y.shape)
    k = rng.normal(size=(8, 2))
    k *= 2 * np.pi / (np.linalg.norm(k, axis=1, keepdims=True) * rng.uniform(1, 3, (8, 1)))
    ph, amp = rng.uniform(0, 2 * np.pi, 8), rng.normal(size=(8, 2))
    field = np.sin(y @ k.T + ph) @ amp
    a = rng.uniform(-np.pi, np.pi)
    r = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    x = (y @ r + bias / np.sqrt(np.mean(np.sum(field ** 2, 1))) * field
         + rng.normal(0, noise / np.sqrt(2), y.shape))
    return x, y


def test_fitted_noise_does_not_collapse_into_a_field_between_neighbours():
    """with sigma fitted, 16 of these 60 cells got noise ~1e-3 of the truth and a
    length scale ~half the spacing (kriging then passed through every fiducial's noise, and the
    decision applied it: targets 1.21-1.40x the uncorrected TRE). The length scale is now at
    least the median neighbour distance when the noise is fitted
    (gp_fit.FITTED_NOISE_MIN_LENGTH)."""
    from rbc_registration.core.interpolation.gp_fit import fit_hyperparameters
    from rbc_registration.core.rigid.restoration import restore_rigid_body
    from scipy.spatial import cKDTree

    for seed in range(60):
        x, y = _weak_bias_grid(seed)
        eps = restore_rigid_body(x, y).corrections
        h = fit_hyperparameters(x, eps)
        spacing = np.median(cKDTree(x).query(x, k=2)[0][:, 1])
        assert h.noise_fitted and h.length_scale >= spacing * (1 - 1e-9), seed
        assert h.noise_std > 0.3 * 1e-4, (seed, h)
        given = fit_hyperparameters(x, eps, sigma=1e-4)           # sigma known: spacing / 4
        assert given.noise_std == pytest.approx(1e-4)
