"""One call's evaluation of targets (core/answers.py): the same numbers as the interpolators' own
calls, one hull location per call, and single targets answered as in a batch."""

import functools

import numpy as np
import pytest
import scipy.linalg

from rbc_registration.core import ModelConfig, build_model
from rbc_registration.core.answers import TargetCorrections
from rbc_registration.core.constants import UNCORRECTED
from rbc_registration.core.interpolation.paper import HullTest
from rbc_registration.core.interpolation.kriging import KrigingInterpolator

#: (interpolation, decision mode, bias of the field) -> the method targets get. ``cv`` with a
#: strong field decides kriging while paper is configured: one call evaluates both (the node's
#: benchmark model); a weak field leaves targets uncorrected although both interpolators exist.
CASES = [("paper", "cv", 3e-3, "kriging"), ("paper", "on", 3e-3, "paper"),
         ("kriging", "on", 3e-3, "kriging"), ("paper", "cv", 1e-6, UNCORRECTED),
         ("kriging", "off", 3e-3, UNCORRECTED)]
FIELDS = ("uncorrected", "corrected", "correction", "inside_hull", "expected_error",
          "destination", "expected_tre", "tre_bound")


@functools.lru_cache(maxsize=None)
def case(d, interpolation, mode, bias):
    """A model of 40 (3D) / 50 (2D) random fiducials and 60 targets: the first 5 on fiducials,
    the others uniform over a box 15 % larger than the fiducials' on each side (a third to a half
    outside the hull)."""
    rng = np.random.default_rng(d)
    x = rng.uniform(0.0, 1.0, (40 if d == 3 else 50, d))
    y = x + bias * np.sin(3.0 * x) + rng.normal(0.0, 1e-4, x.shape)
    model = build_model(x, y, ModelConfig(dimension=d, interpolation=interpolation,
                                          decision=mode, sigma=1.7e-4))
    targets = rng.uniform(-0.15, 1.15, (60, d))
    targets[:5] = x[:5]
    return model, targets


def reference(model, t):
    """``correct`` composed from the public pieces, each interpolator validating and locating the
    targets itself (the general path before the shared evaluation)."""
    interp = model.interpolator(t)
    method = model.decision.method
    uncorrected = model.uncorrected.apply(t)
    if method == UNCORRECTED:
        destination, inside = model.uncorrected.apply(t), interp.inside_hull
    else:
        chosen = model.interpolators[method](t)
        destination, inside = model.corrected.apply(t - chosen.correction), chosen.inside_hull
    errors = model.decision.error_model
    scale = model.fit_geometry.beyond(t)
    if errors.scaled:
        kriging = model.interpolators["kriging"]
        scale = scale * np.hypot(kriging(t).expected_error, kriging.noise_axis_std)
    expected, bound = errors.at(scale)
    corrections = (uncorrected, model.corrected.apply(t - interp.correction), interp.correction,
                   interp.inside_hull, interp.expected_error, destination, expected, bound)
    return corrections, (destination, expected, bound, inside, method)


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("interpolation, mode, bias, method", CASES,
                         ids=[f"{c[0]}-{c[1]}-{c[3]}" for c in CASES])
def test_answers_equal_the_interpolators_own_exactly(d, interpolation, mode, bias, method):
    """Every field of ``correct`` and ``answer`` is bit for bit what the interpolators' own calls
    give, for single targets, a few and the whole batch (2D: 60 >= GRID_MIN_TARGETS takes the
    sector grid), inside and outside the hull and on fiducials."""
    model, targets = case(d, interpolation, mode, bias)
    assert model.decision.method == method and model.config.interpolation == interpolation
    inside = model.interpolator(targets).inside_hull
    assert 10 < inside.sum() < len(targets) - 10         # both kinds of target, many of each
    for t in [targets[k:k + 1] for k in range(len(targets))] + [targets[:4], targets]:
        want_corrections, want_answer = reference(model, t)
        tc, ans = model.correct(t), model.answer(t)
        for name, got, want in zip(FIELDS, tc, want_corrections):
            np.testing.assert_array_equal(got, want, err_msg=f"{name}, K = {len(t)}")
            assert got.dtype == want.dtype and got.shape == want.shape, name
        for got, want in zip(ans[:4], want_answer[:4]):
            np.testing.assert_array_equal(got, want, err_msg=f"answer, K = {len(t)}")
        assert ans.method == method


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("interpolation, mode, bias, method", CASES,
                         ids=[f"{c[0]}-{c[1]}-{c[3]}" for c in CASES])
def test_single_targets_are_answered_as_in_a_batch(d, interpolation, mode, bias, method):
    """Target k alone gets what it gets in the batch: hull flags exactly, the numbers to BLAS
    rounding (one row is a matrix-vector product, a batch a matrix product; kriging's weights
    cancel, so its mean and error keep that rounding relative to the field, ~1e-12 of its largest
    value, as before the shared evaluation; without kriging a few ulps)."""
    model, targets = case(d, interpolation, mode, bias)
    batch = model.correct(targets)
    singles = [model.correct(targets[k:k + 1]) for k in range(len(targets))]
    rounding = 1e-10 if "kriging" in (method, interpolation) else 1e-14    # else a few ulps
    for name, field in zip(FIELDS, batch):
        one = np.concatenate([getattr(s, name) for s in singles])
        if field.dtype == bool:
            np.testing.assert_array_equal(one, field, err_msg=name)
        else:
            np.testing.assert_allclose(one, field, rtol=0,
                                       atol=rounding * np.nanmax(np.abs(field), initial=1e-300),
                                       err_msg=name)


def test_one_hull_location_per_call(monkeypatch):
    """The paper interpolation and kriging share one hull test, and a call that evaluates both
    locates its targets once."""
    model, targets = case(3, "paper", "cv", 3e-3)
    assert model.interpolators["paper"].hull is model.interpolators["kriging"].hull
    calls = []
    located = HullTest.simplices
    monkeypatch.setattr(HullTest, "simplices", lambda self, t: calls.append(len(t))
                        or located(self, t))
    model.correct(targets[:1])
    model.answer(targets[:3])
    assert calls == [1, 3]
    model.interpolators["kriging"](targets[:2])       # the public call locates by itself
    assert calls == [1, 3, 2]


@pytest.mark.parametrize("interpolation, mode", [("paper", "off"), ("paper", "on")])
def test_corrections_fields_are_separate_arrays(interpolation, mode):
    """``destination`` equals ``uncorrected`` (off) or ``corrected`` (on) but is its own array."""
    model, targets = case(3, interpolation, mode, 3e-3)
    tc = model.correct(targets[:2])
    same = tc.uncorrected if mode == "off" else tc.corrected
    np.testing.assert_array_equal(tc.destination, same)
    tc.destination[:] = 0.0
    assert not np.shares_memory(tc.destination, same) and (same != 0.0).all()


@pytest.mark.parametrize("order", ["F", "C"])
def test_kriging_lower_solve_is_solve_triangular(order):
    """The direct LAPACK solve gives solve_triangular's numbers exactly, for the factor held as L
    or as L^T (a C-ordered factor takes solve_triangular itself); either is L^-1 b."""
    rng = np.random.default_rng(4)
    x = rng.uniform(0.0, 1.0, (30, 3))
    k = KrigingInterpolator(x, 1e-3 * np.sin(3.0 * x), sigma=1e-4)
    if order == "C":
        k.chol = (np.ascontiguousarray(k.chol[0]), k.chol[1])
    factor, lower = k.chol
    low = factor if lower else factor.T
    for chol in (k.chol, (np.asfortranarray(low), True), (np.ascontiguousarray(low.T), False)):
        k.chol = chol                                  # each layout and triangle
        for cols in (1, 5):
            b = rng.normal(size=(cols, 30))
            want = scipy.linalg.solve_triangular(chol[0], b.T, lower=chol[1],
                                                 trans=0 if chol[1] else 1, check_finite=False)
            np.testing.assert_array_equal(k._lower_solve(b.copy().T), want)
            np.testing.assert_allclose(want, scipy.linalg.solve_triangular(
                low, b.T, lower=True, check_finite=False), rtol=1e-12, atol=0.0)


def test_tetrahedra_without_masks_equal_the_masked_path():
    """All targets inside the hull skip the masks; the weights are those the masked path (one
    target outside) gives the same targets."""
    model, targets = case(3, "paper", "on", 3e-3)
    paper = model.interpolators["paper"]
    inside = targets[paper(targets).inside_hull]
    outside = targets[~paper(targets).inside_hull][:1]
    idx, w, flags = paper.weights(inside)
    idx_mixed, w_mixed, flags_mixed = paper.weights(np.vstack([inside, outside]))
    assert flags.all() and not flags_mixed[-1]
    np.testing.assert_array_equal(idx, idx_mixed[:-1])
    np.testing.assert_array_equal(w, w_mixed[:-1])
    assert idx.dtype == idx_mixed.dtype == np.intp


def test_a_thin_cell_the_registration_accepts_is_answered():
    """Fiducials along a beam with 1e-4 off-axis spread: build_model accepts them, and the
    factor of the bound beyond the fiducials must not refuse them afterwards (every
    answer raised 'cannot fix a rigid registration')."""
    from scipy.spatial.transform import Rotation
    rng = np.random.default_rng(0)
    x = np.linspace(0, 1000, 30)[:, None] * np.ones(3) / np.sqrt(3)
    x = x + rng.normal(scale=1e-4, size=x.shape)
    y = x @ Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix().T + 50.0
    m = build_model(x, y + rng.normal(scale=0.01, size=y.shape),
                    ModelConfig(dimension=3, interpolation="kriging"))
    a = m.answer(x[:2] + 1.0)
    assert np.all(np.isfinite(a.destination)) and np.all(a.tre_bound > 0)


def test_a_model_answers_with_the_types_of_core_answers():
    model, targets = case(3, "paper", "cv", 3e-3)
    answer = model.correct(targets)
    assert isinstance(answer, TargetCorrections)
    assert model.decision.method == "kriging" and answer.destination.shape == targets.shape
    assert np.all(answer.tre_bound >= answer.expected_tre)
