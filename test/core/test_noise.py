"""Noise sigma from repeats (section 4) and the rho rule (section 6)."""

import math

import numpy as np
import pytest

from rbc_registration.core.noise import assess, estimate_sigma


def test_sigma_is_rms_scatter_of_one_measurement():
    rng = np.random.default_rng(0)
    groups = [rng.normal(size=(400, 3)) * 0.1 + k for k in range(30)]
    # per-axis 0.1 -> RMS over the 3 axes 0.1 * sqrt(3)
    assert estimate_sigma(groups) == pytest.approx(0.1 * math.sqrt(3), rel=0.03)


def test_single_measurements_give_no_sigma():
    assert estimate_sigma([np.zeros((1, 2)), np.ones((1, 2))]) is None


def test_sigma_skips_single_measurement_fiducials():
    groups = [np.array([[0.0, 0.0], [0.0, 2.0]]), np.array([[5.0, 5.0]])]
    assert estimate_sigma(groups) == pytest.approx(math.sqrt(2.0))


@pytest.mark.parametrize("sigma_l0, sigma, rec", [
    (0.9, 1.0, "do_not_apply"), (1.0, 1.0, "uncertain"), (2.49, 1.0, "uncertain"),
    (2.5, 1.0, "apply"), (1.0, None, "unknown"), (1.0, 0.0, "apply")])
def test_rule(sigma_l0, sigma, rec):
    a = assess(sigma_l0, sigma)
    assert a.recommendation == rec
    if sigma:
        assert a.rho == pytest.approx(sigma_l0 / sigma)


@pytest.mark.parametrize("args, message", [
    ((1.0, -1.0), "sigma"), ((math.nan, 1.0), "sigma_L0"),
    ((1.0, 1.0, 3.0, 2.0), r"rho_reject \(3\) must be <= rho_apply \(2\)"),
    ((1.0, math.inf), "sigma")])
def test_rule_validation(args, message):
    with pytest.raises(ValueError, match=message):
        assess(*args)


def test_repeats_with_nan():
    with pytest.raises(ValueError, match="NaN"):
        estimate_sigma([np.array([[0.0, np.nan], [1.0, 1.0]])])
