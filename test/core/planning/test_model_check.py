"""The error model against the cross-validated held-out errors (core/planning/model_check.py)."""

import dataclasses
import json
import math
import types

import numpy as np
import pytest

from rbc_registration.core import ModelConfig, build_model
from rbc_registration.core.decision.crossval import fold_groups
from rbc_registration.core.planning.expected_error import (ExpectedErrorModel,
                                                           expected_squared_errors,
                                                  pooled_median)
from rbc_registration.core.decision.groups import group_labels
from rbc_registration.core.planning.model_check import (TRUST_FACTOR, TRUST_MIN_UNITS, ModelCheck,
                                               check_model, expected_held_out, units_to_trust)
from rbc_registration.core.planning.model_planner import calibrated, error_model_from
from rbc_registration.core.synthetic.cells import make_cell


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("corrected", [True, False])
def test_expected_held_out_is_the_expected_error_of_each_fold_from_the_others(d, corrected):
    """Each fold's expected error equals planning it afresh from the fiducials outside it
    (bias posterior, rigid fit and the held-out point's own noise), for single fiducials and
    for folds of several held out together."""
    rng = np.random.default_rng(2)
    x = rng.uniform(0, 4, (14, d))
    counts = rng.integers(1, 4, len(x)).astype(float)
    em = ExpectedErrorModel.from_axis_std(0.6, 1.7, np.array([0.05, 0.03, 0.02])[:d], corrected)
    loo = [np.array([k]) for k in range(len(x))]
    pairs = [np.array([k, k + 7]) for k in range(7)]
    for folds in (loo, pairs):
        got = expected_held_out(x, counts, folds, em)
        for s in folds:
            keep = np.setdiff1d(np.arange(len(x)), s)
            for k in s:
                want = expected_squared_errors(x[keep], x[k:k + 1], em, counts[keep],
                                               float(counts[k]))[0]
                assert got[k] == pytest.approx(want, rel=1e-7)
    scaled = expected_held_out(x, counts, loo, dataclasses.replace(em, calibration=2.0))
    np.testing.assert_allclose(scaled, 4 * expected_held_out(x, counts, loo, em), rtol=1e-12)


def _model(n, seed=1):
    cell = make_cell("RA", seed=seed)
    x = np.array([m[0] for m in cell.fiducial_measurements])
    pick = np.random.default_rng(0).permutation(len(x))[:n]
    cfg = ModelConfig(dimension=2, interpolation="kriging", sigma=cell.spec.sigma)
    return build_model(x[pick], cell.fiducial_truth[pick], cfg)


@pytest.fixture(scope="module")
def forty():
    return _model(40)


def test_the_check_compares_the_cross_validated_median_with_the_expected_one(forty):
    m = forty
    em = error_model_from(m)
    check = check_model(m, em)
    cv = m.decision.cross_validation
    assert check.available and check.units == cv.n_units == 40
    assert check.cross_validated_median == pytest.approx(np.median(cv.errors["kriging"]))
    assert check.ratio == pytest.approx(check.cross_validated_median / check.expected_median)
    assert 1 / TRUST_FACTOR <= check.ratio <= TRUST_FACTOR
    assert check.trustworthy and check.note == ""
    # the check is of the uncalibrated model: a calibration given does not change it
    again = check_model(m, dataclasses.replace(em, calibration=3.0))
    assert again.ratio == pytest.approx(check.ratio, rel=1e-12)
    # calibrated(): the planning model times the ratio
    cal, same = calibrated(m)
    assert same == check and cal.calibration == check.ratio
    assert (cal.signal_std, cal.length_scale) == (em.signal_std, em.length_scale)


def test_a_ratio_beyond_the_factor_is_not_trusted(forty):
    m = forty
    em = error_model_from(m)
    small = dataclasses.replace(em, noise_covariance=em.noise_covariance / 100,
                                signal_std=em.signal_std / 10)
    check = check_model(m, small)
    assert check.available and check.ratio > TRUST_FACTOR and not check.trustworthy
    assert f"not within {TRUST_FACTOR:g} x" in check.note
    assert units_to_trust(check) == 0


def test_too_few_held_out_fiducials_are_not_trusted():
    m = _model(12)
    check = check_model(m, error_model_from(m))
    assert check.available and check.units == 12 < TRUST_MIN_UNITS and not check.trustworthy
    assert check.note.startswith(f"12 held-out fiducials, fewer than the {TRUST_MIN_UNITS}")
    assert units_to_trust(check) == TRUST_MIN_UNITS - 12
    d = check.to_dict()
    assert d["units"] == 12 and d["min_units"] == TRUST_MIN_UNITS and d["factor"] == TRUST_FACTOR
    assert d["ratio"] == pytest.approx(check.ratio) and d["trustworthy"] is False


def test_without_cross_validated_kriging_errors_the_check_is_unavailable(forty):
    m = forty
    cv = m.decision.cross_validation
    no_kriging = cv._replace(errors={k: v for k, v in cv.errors.items() if k != "kriging"},
                             unavailable={"kriging": "not asked"})

    stub = types.SimpleNamespace(**{k: getattr(m, k) for k in ("working", "destination",
                                                                "counts", "groups")})
    stub.decision = types.SimpleNamespace(cross_validation=no_kriging)
    check = check_model(stub, error_model_from(m))
    assert not check.available and not check.trustworthy and check.ratio == 1.0
    assert check.note == "no cross-validated errors of kriging: not asked"
    d = json.loads(json.dumps(check.to_dict()))                  # NaN as None: valid JSON
    assert d["expected_held_out_median"] is None and d["cross_validated_median"] is None
    assert isinstance(check, ModelCheck) and math.isnan(check.expected_median)


def test_pooled_median_of_the_expected_held_out_errors_is_the_expected_median(forty):
    m = forty
    em = error_model_from(m)
    check = check_model(m, em)
    cv = m.decision.cross_validation
    folds = fold_groups(m.working, cv.scheme, m.destination, group_labels(m.groups, 40))
    assert sorted(np.concatenate(folds)) == list(range(40))
    e = expected_held_out(m.working, m.counts, folds, em)
    assert check.expected_median == pytest.approx(float(pooled_median(e, 2)), rel=1e-12)
