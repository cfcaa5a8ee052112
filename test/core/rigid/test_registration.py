"""Rigid registration: round trips, proper rotations, weights, and one test per validation rule."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rbc_registration.core.rigid.registration import fre_rms, rigid_fit


def _rot2(a):
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


@pytest.mark.parametrize("dim", [2, 3])
def test_recovers_known_transform(dim):
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (20, dim))
    r = _rot2(0.7) if dim == 2 else Rotation.from_rotvec([0.3, -0.2, 1.1]).as_matrix()
    t = rng.normal(size=dim)
    fit = rigid_fit(x, x @ r.T + t)
    np.testing.assert_allclose(fit.rotation, r, atol=1e-12)
    np.testing.assert_allclose(fit.translation, t, atol=1e-12)
    assert fit.fre_rms < 1e-12
    # round trip: apply then invert
    np.testing.assert_allclose(fit.inverse_apply(fit.apply(x)), x, atol=1e-12)


def test_never_returns_a_reflection():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(10, 3))
    y = x * np.array([1, 1, -1])            # a mirror image: best orthogonal map is a reflection
    fit = rigid_fit(x, y)
    assert np.linalg.det(fit.rotation) == pytest.approx(1.0)
    np.testing.assert_allclose(fit.rotation @ fit.rotation.T, np.eye(3), atol=1e-12)


def test_fre_matches_eq2():
    rng = np.random.default_rng(2)
    x = rng.normal(size=(15, 3))
    y = x + rng.normal(scale=0.01, size=x.shape)
    fit = rigid_fit(x, y)
    res = fit.apply(x) - y
    assert fit.fre_rms == pytest.approx(np.sqrt(np.mean(np.sum(res ** 2, axis=1))))
    assert fre_rms(fit, x, y) == pytest.approx(fit.fre_rms)


def test_weights_ignore_zero_weighted_outlier():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(8, 3))
    y = x + 1.0
    y[0] += 50.0
    w = np.ones(8)
    w[0] = 0.0
    fit = rigid_fit(x, y, w)
    np.testing.assert_allclose(fit.translation, np.ones(3), atol=1e-12)


@pytest.mark.parametrize("x, y, message", [
    pytest.param(np.zeros((2, 3)), np.zeros((2, 3)), "at least 3", id="too-few"),
    pytest.param(np.zeros((4, 3)), np.zeros((4, 2)), "shape", id="2d-vs-3d"),
    pytest.param(np.ones((4, 3)), np.ones((4, 3)), "coincident", id="coincident"),
    pytest.param(np.outer(np.arange(5.0), [1, 2, 3]), np.outer(np.arange(5.0), [1, 2, 3]),
                 "collinear", id="collinear"),
    pytest.param(np.array([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]]), np.eye(3), "NaN", id="nan"),
    pytest.param(np.array([[0, 0, np.inf], [1, 0, 0], [0, 1, 0]]), np.eye(3), "NaN or inf",
                 id="inf"),
    pytest.param(np.zeros((4, 4)), np.zeros((4, 4)), "shape", id="4-columns"),
    pytest.param(np.array([[0, 0, 1e300], [1, 0, 0], [0, 1, 0]]), np.eye(3), "beyond",
                 id="1e300"),
    pytest.param(np.array([[0, 0, 1e13], [1, 0, 0], [0, 1, 0]]), np.eye(3), "beyond ±1e\\+12",
                 id="1e13"),
])
def test_validation(x, y, message):
    with pytest.raises(ValueError, match=message):
        rigid_fit(x, y)


def test_text_is_a_type_error():
    with pytest.raises(TypeError, match="numeric"):
        rigid_fit([["a", "b", "c"]] * 3, np.eye(3))


@pytest.mark.parametrize("w, message", [
    (np.ones(3), "shape"), (-np.ones(4), "non-negative"), (np.zeros(4), "not all zero"),
    (np.array([1, 1, 1, np.nan]), "finite")])
def test_bad_weights(w, message):
    x = np.random.default_rng(0).normal(size=(4, 3))
    with pytest.raises(ValueError, match=message):
        rigid_fit(x, x, w)


@pytest.mark.parametrize("offset", [0.0, 6.4e6, 1e9])
def test_a_narrow_cell_far_from_the_origin_is_the_same_cell(offset):
    """A 2 m x 4 mm rail registers alike at the origin and in geodetic coordinates (6.4e6 m;
    a 1e-9 relative tolerance called it collinear there), and a collinear or coincident set is
    still refused there: the tolerance follows the coordinates' rounding, not a fixed fraction."""
    rng = np.random.default_rng(8)
    rail = rng.uniform([-1, -2e-3, -2e-3], [1, 2e-3, 2e-3], (20, 3))
    r = Rotation.from_rotvec([0.1, -0.3, 0.5]).as_matrix()
    t = np.array([0.3, -0.2, 0.1])
    fit = rigid_fit(rail + offset, (rail @ r.T + t) + offset)
    # the coordinates' rounding over the rail's half-width: what no fit can do better than
    rounding_angle = np.finfo(float).eps * offset / 2e-3
    np.testing.assert_allclose(fit.rotation, r, atol=1e-12 + rounding_angle)
    line = np.outer(np.linspace(-1, 1, 20), [1.0, 0.5, 0.2]) + offset
    with pytest.raises(ValueError, match="collinear"):
        rigid_fit(line, line)
    with pytest.raises(ValueError, match="coincident"):
        rigid_fit(np.full((5, 3), offset + 1.0), np.full((5, 3), offset + 1.0))
