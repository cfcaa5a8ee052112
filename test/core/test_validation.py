"""The input checks every core function runs first (core/validation.py): shapes, counts, NaN and
huge coordinates, spread, subsets and the rounding rule, each refused naming what was wrong."""

import numpy as np
import pytest

from rbc_registration.core.validation import (MAX_ABS_COORDINATE, RESOLUTION, as_point_pairs,
                                              as_points, check_spread, check_subset, rounding)


def test_as_points_returns_float64_and_accepts_lists():
    pts = as_points([[1, 2, 3], [4, 5, 6]])
    assert pts.dtype == np.float64 and pts.shape == (2, 3)


@pytest.mark.parametrize("points, match", [
    ([1.0, 2.0, 3.0], r"fiducials must have shape \(N, 2\) or \(N, 3\), got \(3,\)"),
    ([[1.0, 2.0, 3.0, 4.0]], r"got \(1, 4\)"),
    ([[0.0, 0.0], [1.0, np.nan]], r"NaN or inf \(first at row 1"),
    ([[0.0, 0.0], [np.inf, 1.0]], r"first at row 1"),
    ([[0.0, 0.0], [2 * MAX_ABS_COORDINATE, 0.0]], r"beyond ±1e\+12 at row 1"),
])
def test_as_points_names_what_is_wrong(points, match):
    with pytest.raises(ValueError, match=match):
        as_points(points, "fiducials")


def test_as_points_dimension_count_and_type():
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        as_points([[0.0, 0.0]], dim=3)
    with pytest.raises(ValueError, match="needs at least 3 points, got 2"):
        as_points([[0.0, 0.0], [1.0, 1.0]], min_count=3)
    with pytest.raises(TypeError, match="must be numeric, got list"):
        as_points([["a", "b"]])


def test_point_pairs_must_match():
    with pytest.raises(ValueError, match=r"same shape, got \(3, 3\) and \(2, 3\)"):
        as_point_pairs(np.zeros((3, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"destination points must have shape \(N, 3\)"):
        as_point_pairs(np.zeros((3, 3)), np.zeros((3, 2)))


def test_check_spread_refuses_coincident_and_collinear_points():
    with pytest.raises(ValueError, match="coincident"):
        check_spread(np.ones((4, 2)), "working points")
    line = np.outer(np.arange(5.0), [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="collinear"):
        check_spread(line)
    check_spread(line[:, :2])                      # a line fixes a 2D registration
    far = np.array([[6.4e6, 0.0, 0.0], [6.4e6 + 2.0, 0.0, 0.0], [6.4e6, 0.01, 0.0]])
    check_spread(far)                              # 2 m x 1 cm far from the origin is a plane


def test_check_subset():
    np.testing.assert_array_equal(check_subset(None, 3, "s"), [0, 1, 2])
    np.testing.assert_array_equal(check_subset([2, 0], 3, "s"), [2, 0])
    for bad, match in (([], "non-empty"), ([0, 3], "out of range 0..2"), ([1, 1], "repeats"),
                       ([0.5], "non-empty list of fiducial indices")):
        with pytest.raises(ValueError, match=match):
            check_subset(bad, 3, "s")


def test_rounding_scales_with_the_largest_coordinate():
    assert rounding(np.array([[1.0, -2000.0]]), np.array([[3.0, 4.0]])) == RESOLUTION * 2000.0
