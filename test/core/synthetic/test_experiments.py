"""The paper's processing of the synthetic cells (core/synthetic/experiments.py): what it feeds the
model."""

import numpy as np
import pytest

from rbc_registration.core.synthetic.experiments import run_cell
from rbc_registration.core.rigid.mismatch import sigma_l
from rbc_registration.core.decision.noise import repeat_stats, sigma_from_stats
from rbc_registration.core.synthetic.cells import make_cell


def test_ra_is_processed_on_single_measurements_as_the_paper_does():
    """The paper measured every RA hole once; 52 holes 16 times, for sigma only. The model must
    get the single measurement of each (the first of a repeated hole) with n_j = 1, and sigma_L0
    = 0.28 mm on those (before: 52 fiducials were 16-point averages)."""
    cell = make_cell("RA", seed=1)
    single = np.array([m[0] for m in cell.fiducial_measurements])
    np.testing.assert_array_equal(cell.fiducial_processed, single)
    assert sigma_l(single, cell.fiducial_truth) == pytest.approx(0.28, rel=1e-4)
    model = run_cell(cell).model
    np.testing.assert_array_equal(model.working, single)
    assert (model.counts == 1).all()
    assert model.sigma == pytest.approx(sigma_from_stats(repeat_stats(cell.fiducial_measurements,
                                                                      2)))
    assert model.sigma_l[0] == pytest.approx(0.28, rel=1e-4)


def test_a_is_processed_on_the_means_of_its_repeats():
    cell = make_cell("A", seed=1, repeats=5)
    model = run_cell(cell, instantaneous_sets=1).model
    np.testing.assert_allclose(model.working, cell.fiducial_means)
    assert (model.counts == 5).all() and model.sigma_source == "repeats"
    # 2.5 mm is the bias alone (the paper's A: averaged points); the means keep a little noise.
    assert model.sigma_l[0] == pytest.approx(sigma_l(cell.fiducial_means, cell.fiducial_truth))
    assert model.sigma_l[0] == pytest.approx(2.5, rel=1e-3)
