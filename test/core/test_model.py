"""The model as the CLI and node use it: config validation, subsets, sigma sources, corrections."""

import numpy as np
import pytest

from rbc_registration.core import ModelConfig, build_model, leave_one_out, target_errors
from rbc_registration.core.synthetic.cells import make_cell


@pytest.fixture(scope="module")
def ra():
    return make_cell("RA", seed=0)


def test_corrected_fiducials_map_exactly(ra):
    m = build_model(ra.fiducial_means, ra.fiducial_truth, ModelConfig(dimension=2))
    assert m.corrected.fre_rms < 1e-9 < m.uncorrected.fre_rms
    # a target at a fiducial gets that fiducial's correction and lands on its destination
    tc = m.correct(m.working[:5])
    np.testing.assert_allclose(tc.corrected, m.destination[:5], atol=1e-8)
    np.testing.assert_allclose(tc.correction, m.corrections[:5], atol=1e-12)


def test_sigma_sources(ra):
    m = build_model(ra.fiducial_means, ra.fiducial_truth, ModelConfig(dimension=2),
                    working_repeats=ra.fiducial_measurements)
    assert m.sigma_source == "repeats" and m.sigma == pytest.approx(0.11, rel=0.15)
    assert m.rho == pytest.approx(m.sigma_l[0] / m.sigma)
    given = build_model(ra.fiducial_means, ra.fiducial_truth, ModelConfig(dimension=2, sigma=0.5))
    assert given.sigma_source == "given" and given.recommendation == "do_not_apply"
    unknown = build_model(ra.fiducial_means, ra.fiducial_truth, ModelConfig(dimension=2))
    assert unknown.sigma is None and unknown.recommendation == "unknown"


def test_subsets_as_in_the_paper(ra):
    cfg = ModelConfig(dimension=2, uncorrected_subset=(0, 40, 120, 200, 270),
                      corrected_subset=(10, 150, 260))
    m = build_model(ra.fiducial_means, ra.fiducial_truth, cfg)
    full = build_model(ra.fiducial_means, ra.fiducial_truth, ModelConfig(dimension=2))
    # any 3 corrected fiducials give the same registration: RBC holds among them
    np.testing.assert_allclose(m.corrected.rotation, full.corrected.rotation, atol=1e-9)
    assert not np.allclose(m.uncorrected.translation, full.uncorrected.translation, atol=1e-6)


@pytest.mark.parametrize("kwargs, message", [
    pytest.param({"dimension": 4}, "dimension", id="dimension"),
    pytest.param({"restoration": "x"}, "restoration", id="restoration"),
    pytest.param({"steps": 0}, "steps", id="steps"),
    pytest.param({"interpolation": "spline"}, "interpolation", id="interpolation"),
    pytest.param({"sigma": 0.0}, "sigma must be a positive finite length or None, got 0.0",
                 id="zero-sigma"),
    pytest.param({"sigma": float("nan")}, "sigma", id="nan-sigma"),
    pytest.param({"sigma_axis": 2e154}, r"sigma_axis must be at most 1e\+12", id="huge-sigma"),
    pytest.param({"rho_reject": 3.0}, r"rho_reject \(3\) must be <= rho_apply \(2.5\)",
                 id="rho-order"),
    pytest.param({"rho_apply": -1.0}, "rho_apply", id="negative-rho")])
def test_config_validation(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ModelConfig(**kwargs)


def test_build_validation(ra):
    x, y = ra.fiducial_means, ra.fiducial_truth
    with pytest.raises(ValueError, match="shape"):
        build_model(x, y, ModelConfig(dimension=3))
    with pytest.raises(ValueError, match="unique"):
        build_model(x[:4], y[:4], ModelConfig(dimension=2), ids=["a", "a", "b", "c"])
    with pytest.raises(ValueError, match="ids"):
        build_model(x[:4], y[:4], ModelConfig(dimension=2), ids=["a"])
    with pytest.raises(ValueError, match="out of range"):
        build_model(x, y, ModelConfig(dimension=2, corrected_subset=(0, 1, 999)))
    with pytest.raises(ValueError, match="repeats"):
        build_model(x[:4], y[:4], ModelConfig(dimension=2), working_repeats=[x[:1]])


def test_target_errors_and_loo(ra):
    m = build_model(ra.fiducial_means, ra.fiducial_truth, ModelConfig(dimension=2),
                    working_repeats=ra.fiducial_measurements)
    err = target_errors(m, ra.target_means, ra.target_truth)
    assert len(err.tre_u) == 80
    np.testing.assert_allclose(err.delta, err.tre_c - err.tre_u)
    loo = leave_one_out(m)
    assert len(loo.tre_u) == len(m.ids)
    # leaving a fiducial out and predicting it: correcting helps on this biased cell
    assert np.median(loo.tre_c) < np.median(loo.tre_u)


@pytest.mark.parametrize("interpolation", ["paper", "kriging"])
def test_zero_sigma_from_identical_repeats(ra, interpolation):
    """Identical repeats (a simulator, a copied export, a rounding driver) are no noise
    estimate: sigma is unknown (a given sigma of 0 is refused), rho and the paper's
    recommendation too (was sigma 0, rho inf, 'apply', and a kriging candidate without noise
    that failed on an exactly rigid cell); the model is built and answers all the same, and a
    sigma given beside them is used."""
    x, y = ra.fiducial_means, ra.fiducial_truth
    repeats = [np.repeat(p[None], 2, axis=0) for p in x]
    model = build_model(x, y, ModelConfig(dimension=2, interpolation=interpolation),
                        working_repeats=repeats)
    assert model.sigma is None and model.sigma_source == "unknown"
    assert model.rho is None and model.recommendation == "unknown"
    assert np.isfinite(model.correct(ra.target_means).corrected).all()
    given = build_model(x, y, ModelConfig(dimension=2, interpolation=interpolation, sigma=0.1),
                        working_repeats=repeats)
    assert given.sigma == 0.1 and given.sigma_source == "given"
    assert given.rho == pytest.approx(given.restoration.sigma_l0 / 0.1)
