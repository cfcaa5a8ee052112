"""Property tests (hypothesis): invariants of the restoration and the model."""

import numpy as np
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from rbc_registration.core import ModelConfig, build_model, restore_rigid_body
from rbc_registration.core.rigid.registration import rigid_fit

seeds = st.integers(0, 2 ** 31 - 1)


def cell(seed, j=30):
    rng = np.random.default_rng(seed)
    y = rng.uniform(-1, 1, (j, 3))
    x = y @ Rotation.from_rotvec(rng.normal(size=3)).as_matrix().T + rng.normal(size=3)
    x += 2e-3 * np.sin(3 * y + rng.uniform(0, 6, 3)) + rng.normal(scale=2e-4, size=y.shape)
    return x, y


def rigid(seed):
    rng = np.random.default_rng(seed)
    return Rotation.from_rotvec(rng.normal(size=3) * 2).as_matrix(), rng.normal(size=3) * 10


@settings(max_examples=25, deadline=None)
@given(seeds, seeds, st.sampled_from(["iterative", "closed-form"]))
def test_moving_either_frame_rigidly_changes_no_correction_magnitude(seed, motion, method):
    x, y = cell(seed)
    base = np.linalg.norm(restore_rigid_body(x, y, method).corrections, axis=1)
    r, t = rigid(motion)
    moved_w = np.linalg.norm(restore_rigid_body(x @ r.T + t, y, method).corrections, axis=1)
    moved_d = np.linalg.norm(restore_rigid_body(x, y @ r.T + t, method).corrections, axis=1)
    np.testing.assert_allclose(moved_w, base, atol=1e-10)
    np.testing.assert_allclose(moved_d, base, atol=1e-10)


@settings(max_examples=25, deadline=None)
@given(seeds, st.sampled_from(["iterative", "closed-form"]))
def test_fre_after_restoration_is_zero(seed, method):
    x, y = cell(seed)
    res = restore_rigid_body(x, y, method)
    assert rigid_fit(res.corrected(x), y).fre_rms < 1e-9
    assert rigid_fit(x, y).fre_rms > 1e-5


@settings(max_examples=15, deadline=None)
@given(seeds, seeds, st.sampled_from(["paper", "kriging"]))
def test_permuting_fiducials_changes_nothing(seed, perm_seed, interpolation):
    x, y = cell(seed)
    perm = np.random.default_rng(perm_seed).permutation(len(x))
    cfg = ModelConfig(dimension=3, interpolation=interpolation, sigma=2e-4 * np.sqrt(3))
    a = build_model(x, y, cfg)
    b = build_model(x[perm], y[perm], cfg)
    np.testing.assert_allclose(b.corrections, a.corrections[perm], atol=1e-10)
    np.testing.assert_allclose(b.sigma_l, a.sigma_l, rtol=1e-8, atol=1e-14)
    np.testing.assert_allclose(b.corrected.rotation, a.corrected.rotation, atol=1e-10)
    targets = np.random.default_rng(seed + 1).uniform(-0.6, 0.6, (5, 3))
    np.testing.assert_allclose(b.correct(targets).corrected, a.correct(targets).corrected,
                               atol=1e-7)


def biased_cell(seed, bias, j=30):
    rng = np.random.default_rng(seed)
    y = rng.uniform(-1, 1, (j, 3))
    x = y @ Rotation.from_rotvec(rng.normal(size=3)).as_matrix().T + rng.normal(size=3)
    x += bias * np.sin(3 * y + rng.uniform(0, 6, 3)) + rng.normal(scale=2e-4, size=y.shape)
    return x, y


def same_decision(a, b, perm=None):
    """Two decisions agree: choice, scores, tests and per-fiducial errors (permuted). Numbers
    agree to 1e-5 relative: kriging's hyper-parameters are optimised to a tolerance (gp_fit.FTOL),
    and rounding moves the optimum within it."""
    assert (a.method, a.apply, a.confident, a.folds) == (b.method, b.apply, b.confident, b.folds)
    for ca, cb in zip(a.candidates, b.candidates):
        assert ca.method == cb.method and ca.available == cb.available
        np.testing.assert_allclose([cb.cv_median, cb.cv_rms, cb.cv_bound],
                                   [ca.cv_median, ca.cv_rms, ca.cv_bound], rtol=1e-5)
        if ca.p_value is not None:
            assert cb.statistic == ca.statistic
            np.testing.assert_allclose(cb.p_value, ca.p_value, rtol=1e-5, atol=1e-300)
        ea = a.cross_validation.errors[ca.method]
        eb = b.cross_validation.errors[cb.method]
        np.testing.assert_allclose(eb, ea if perm is None else ea[perm], rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose([b.error_model.median_factor, b.error_model.bound_factor],
                               [a.error_model.median_factor, a.error_model.bound_factor],
                               rtol=1e-5)


biases = st.sampled_from([0.0, 3e-4, 3e-3])


@settings(max_examples=12, deadline=None)
@given(seeds, seeds, biases, st.sampled_from(["working", "destination"]))
def test_decision_is_invariant_to_rigid_motion_of_either_frame(seed, motion, bias, frame):
    x, y = biased_cell(seed, bias)
    targets = np.random.default_rng(seed + 1).uniform(-0.6, 0.6, (5, 3)) @ np.eye(3)
    targets_w = build_model(x, y, ModelConfig(decision="off")).uncorrected.inverse_apply(targets)
    r, t = rigid(motion)
    a = build_model(x, y, ModelConfig())
    if frame == "working":
        b = build_model(x @ r.T + t, y, ModelConfig())
        tb = b.correct(targets_w @ r.T + t)
        dest_b = tb.destination
    else:
        b = build_model(x, y @ r.T + t, ModelConfig())
        tb = b.correct(targets_w)
        dest_b = (tb.destination - t) @ r                 # back into the original destination
    same_decision(a.decision, b.decision)
    ta = a.correct(targets_w)
    np.testing.assert_allclose(dest_b, ta.destination, atol=1e-7)
    np.testing.assert_allclose(tb.tre_bound, ta.tre_bound, rtol=1e-5)


@settings(max_examples=12, deadline=None)
@given(seeds, seeds, biases)
def test_decision_is_invariant_to_permutation_of_the_fiducials(seed, perm_seed, bias):
    x, y = biased_cell(seed, bias)
    perm = np.random.default_rng(perm_seed).permutation(len(x))
    a = build_model(x, y, ModelConfig())
    b = build_model(x[perm], y[perm], ModelConfig())
    same_decision(a.decision, b.decision, perm)
    targets = a.uncorrected.inverse_apply(np.random.default_rng(seed).uniform(-0.6, 0.6, (5, 3)))
    np.testing.assert_allclose(b.correct(targets).expected_tre, a.correct(targets).expected_tre,
                               rtol=1e-5)
