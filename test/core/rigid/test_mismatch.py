"""Pairwise mismatch L (eq. 1), sigma_L (eq. 7), histograms."""

import numpy as np
import pytest

from rbc_registration.core.rigid import mismatch


def test_matches_brute_force():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(7, 3))
    y = rng.normal(size=(7, 3))
    want = [np.linalg.norm(x[i] - x[j]) - np.linalg.norm(y[i] - y[j])
            for i in range(7) for j in range(i + 1, 7)]
    np.testing.assert_allclose(mismatch.pairwise_mismatch(x, y), want)
    assert mismatch.sigma_l(x, y) == pytest.approx(np.std(want))   # 1/J_p, eq. 7


def test_blocked_path_equals_single_block(monkeypatch):
    rng = np.random.default_rng(1)
    x = rng.normal(size=(300, 3))
    y = x + rng.normal(scale=1e-3, size=x.shape)
    whole = mismatch.pairwise_mismatch(x, y)
    s = mismatch.sigma_l(x, y)
    monkeypatch.setattr(mismatch, "ROWS_PER_BLOCK", 7)
    monkeypatch.setattr(mismatch, "ONE_BLOCK_PAIRS", 100)
    np.testing.assert_array_equal(mismatch.pairwise_mismatch(x, y), whole)
    assert mismatch.sigma_l(x, y) == pytest.approx(s, rel=1e-9)


def test_rigid_copy_has_zero_mismatch():
    x = np.random.default_rng(2).normal(size=(20, 2))
    assert mismatch.sigma_l(x, x + 3.0) < 1e-14


def test_histogram_counts_every_pair():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(30, 3))
    h = mismatch.mismatch_histogram(x, x + rng.normal(scale=0.01, size=x.shape), bins=12)
    assert h.counts.sum() == 30 * 29 // 2
    assert len(h.edges) == 13
    with pytest.raises(ValueError, match="bins"):
        mismatch.mismatch_histogram(x, x, bins=0)


def test_needs_two_points():
    with pytest.raises(ValueError, match="at least 2"):
        mismatch.sigma_l(np.zeros((1, 3)), np.zeros((1, 3)))
