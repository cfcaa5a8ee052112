"""core/saved_model: a model rebuilt from the parts a saved calibration holds answers targets as
the model they were taken from (every field of ``correct`` and ``answer``), without fitting or
cross-validating; parts that do not fit together are refused naming what is wrong."""

import numpy as np
import pytest

from rbc_registration.core import ModelConfig, build_model
from rbc_registration.core.rigid.registration import Registration
from rbc_registration.core.saved_model import needed_interpolations, parts_of, saved_model
from rbc_registration.core.synthetic.cells import make_cell


@pytest.fixture(scope="module")
def ra():
    return make_cell("RA", seed=0)


def _targets(working, n=30, seed=3):
    """Targets over the fiducials' bounding box grown by 20 %: inside and outside the hull."""
    rng = np.random.default_rng(seed)
    lo, hi = working.min(axis=0), working.max(axis=0)
    return lo + (hi - lo) * rng.uniform(-0.2, 1.2, (n, working.shape[1]))


@pytest.mark.parametrize("interpolation, decision", [("paper", "on"), ("kriging", "on"),
                                                     ("kriging", "cv"), ("paper", "off")])
def test_the_parts_answer_as_the_model(ra, interpolation, decision):
    model = build_model(ra.fiducial_means, ra.fiducial_truth,
                        ModelConfig(dimension=2, interpolation=interpolation, decision=decision),
                        working_repeats=ra.fiducial_measurements)
    saved = saved_model(parts_of(model))
    assert saved.decision.method == model.decision.method
    assert saved.decision.apply == (model.decision.method != "uncorrected")
    assert set(saved.interpolators) == set(needed_interpolations(
        interpolation, model.decision.method, model.decision.error_model.scaled))
    targets = _targets(model.working)
    live, got = model.correct(targets), saved.correct(targets)
    assert got.inside_hull.tolist() == live.inside_hull.tolist() and 0 < live.inside_hull.sum()
    assert not live.inside_hull.all()
    for field in ("corrected", "uncorrected", "destination", "correction"):
        np.testing.assert_allclose(getattr(got, field), getattr(live, field), rtol=0,
                                   atol=1e-12, err_msg=field)
    np.testing.assert_allclose(got.expected_tre, live.expected_tre, rtol=1e-12)
    np.testing.assert_allclose(got.tre_bound, live.tre_bound, rtol=1e-12)
    a, b = model.answer(targets[:3]), saved.answer(targets[:3])
    np.testing.assert_allclose(np.asarray(b.destination), np.asarray(a.destination), rtol=0,
                               atol=1e-12)


def test_needed_interpolations_are_those_the_answers_evaluate():
    assert needed_interpolations("paper", "uncorrected", False) == ("paper",)
    assert needed_interpolations("paper", "kriging", False) == ("paper", "kriging")
    assert needed_interpolations("paper", "paper", True) == ("paper", "kriging")
    assert needed_interpolations("kriging", "uncorrected", False) == ("kriging",)


def test_parts_that_do_not_fit_together_are_refused(ra):
    model = build_model(ra.fiducial_means, ra.fiducial_truth,
                        ModelConfig(dimension=2, interpolation="kriging", decision="on"),
                        working_repeats=ra.fiducial_measurements)
    parts = parts_of(model)
    with pytest.raises(ValueError, match="ids and .* repeat counts"):
        saved_model(parts._replace(ids=parts.ids[:-1]))
    with pytest.raises(ValueError, match="interpolation must be one of"):
        saved_model(parts._replace(interpolation="linear"))
    with pytest.raises(ValueError, match="method must be one of"):
        saved_model(parts._replace(method="spline"))
    with pytest.raises(ValueError, match=r"uncorrected: needs a 2 x 2 rotation"):
        saved_model(parts._replace(uncorrected=Registration(np.eye(3), np.zeros(3), 0.0)))
    with pytest.raises(ValueError, match="kriging is needed .* hyper-parameters are missing"):
        saved_model(parts._replace(kriging=None))
