"""Noise sigma from repeats (section 4) and the rho rule (section 6)."""

import math

import numpy as np
import pytest

from rbc_registration.core.decision.noise import assess, estimate_sigma


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


def _repeats(seed, n_fiducials=30, n=5, noise=0.02):
    rng = np.random.default_rng(seed)
    return [rng.uniform(0, 1000, 3) + rng.normal(scale=noise, size=(n, 3))
            for _ in range(n_fiducials)]


def test_one_bad_repeat_that_dominates_sigma_is_named():
    """one repeat 5 mm off (within the 48 mm outlier limit) raised sigma 12x
    and turned rho from 4.47 'apply' into 0.52 'do_not_apply', no word."""
    from rbc_registration.core.decision.noise import repeat_stats, scattered_repeats

    repeats = _repeats(0)
    ids = [f"F{k:02d}" for k in range(30)]
    assert scattered_repeats(ids, repeat_stats(repeats), "mm") is None
    repeats[3][1, 0] += 5.0
    text = scattered_repeats(ids, repeat_stats(repeats), "mm")
    assert text.startswith("fiducial(s) 'F03' (")
    assert "over 10x the median of the 30 fiducials measured more than once" in text
    sigma_with = estimate_sigma(repeats)
    assert f"sigma is {sigma_with:.4g} mm with them" in text


@pytest.mark.parametrize("seed", range(20))
def test_noise_alone_names_no_fiducial_even_with_two_measurements(seed):
    from rbc_registration.core.decision.noise import repeat_stats, scattered_repeats

    repeats = _repeats(seed, n_fiducials=200, n=2)
    assert scattered_repeats([str(k) for k in range(200)], repeat_stats(repeats), "mm") is None


def test_too_few_repeated_fiducials_or_no_scatter_name_nothing():
    from rbc_registration.core.decision.noise import repeat_stats, scattered_repeats

    repeats = _repeats(1, n_fiducials=4)
    repeats[0][0] += 100.0
    assert scattered_repeats(list("abcd"), repeat_stats(repeats), "mm") is None
    same = [np.repeat(np.array([[k, 0.0, 0.0]]), 3, axis=0) for k in range(8)]
    assert scattered_repeats(list("abcdefgh"), repeat_stats(same), "mm") is None


def test_identical_repeats_give_sigma_exactly_zero_and_a_warning():
    """Bit-identical repeats gave sigma 7e-14 mm (np.var's mean of equal values is off by an
    ulp) and rho 9e11 'apply' without a word; now sigma is 0 (the model takes it as unknown)
    and one line names the cause; with sigma given the line says it is used (it said
    'taken as unknown')."""
    from rbc_registration.core.decision.noise import (identical_repeats, repeat_stats,
                                                      sigma_from_stats)
    rng = np.random.default_rng(4)
    points = rng.uniform(0, 1000, (30, 3)) + 0.1234567
    stats = repeat_stats([np.repeat(p[None], 3, axis=0) for p in points])
    assert sigma_from_stats(stats) == 0.0
    text = identical_repeats(stats)
    assert text is not None and "\n" not in text and "all 30 fiducial(s)" in text
    assert text.endswith("sigma is taken as unknown; give the noise as sigma")
    assert identical_repeats(stats, "given").endswith("; the given sigma is used")
    assert identical_repeats(repeat_stats([p[None] for p in points])) is None


def test_repeats_identical_for_most_fiducials_are_named():
    """29 of 30 fiducials with copied repeats and one measured for real gave sigma
    0.18 of the real one's, rho 5x too high, and no warning. When at least half of the
    fiducials measured more than once have repeats identical to their first measurement, one
    line names them. sigma keeps them (a second review: leaving them out made sigma 45 % too
    high on repeats rounded coarser than the noise, where the zeros are data); a few
    coincidences get no line."""
    from rbc_registration.core.decision.noise import (identical_repeats, repeat_stats,
                                                      sigma_from_stats)
    rng = np.random.default_rng(4)
    points = rng.uniform(0, 1000, (30, 3))
    copied = [np.repeat(p[None], 3, axis=0) for p in points]
    copied[5] = copied[5] + rng.normal(0, 0.01, (3, 3))
    stats = repeat_stats(copied)
    assert sigma_from_stats(stats) == pytest.approx(np.sqrt(stats.variances[5] / 30), rel=1e-12)
    text = identical_repeats(stats)
    assert text.startswith("the repeats of 29 of the 30 fiducials measured more than once are "
                           "identical to their first measurement (")
    assert text.endswith("sigma from these repeats is no noise estimate (too small if they "
                         "are copies, mostly rounding if rounded); give the noise as sigma if "
                         "it is known") and "\n" not in text
    assert identical_repeats(stats, "given").endswith("): the given sigma is used")
    # 3 coincidences among 30 noisy fiducials: noise, no line
    noisy = [p + rng.normal(0, 0.01, (3, 3)) for p in points]
    for k in (1, 2, 3):
        noisy[k] = np.repeat(points[k][None], 3, axis=0)
    assert identical_repeats(repeat_stats(noisy)) is None


def test_repeat_variance_keeps_its_digits_far_from_the_origin():
    """The variance about the first measurement: at a 1e6 offset it is the centred one's."""
    from rbc_registration.core.decision.noise import repeat_stats
    rng = np.random.default_rng(5)
    group = rng.normal(0, 0.01, (5, 3))
    near = repeat_stats([group]).variances[0]
    far = repeat_stats([group + 1e6]).variances[0]
    assert near == pytest.approx(float(np.sum(np.var(group, axis=0, ddof=1))), rel=1e-12)
    assert far == pytest.approx(near, rel=1e-6)
