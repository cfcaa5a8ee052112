"""Fiducials in groups: labels, held out whole, the paired test per group, the weighted bound,
and the warning for groups not given (core/decision/groups.py)."""

import numpy as np
import pytest

from rbc_registration.core.decision.crossval import cross_validate, fold_groups, fold_scheme
from rbc_registration.core.decision.choice import conformal_quantile, paired_test
from rbc_registration.core.decision.groups import (group_labels, merge_labels, undeclared_groups,
                                          unit_means, weighted_quantile)
from rbc_registration.core.model import ModelConfig, build_model
from rbc_registration.core.synthetic.structure import make_robot_cell


def test_labels_number_groups_in_order_and_empty_is_its_own():
    labels = group_labels(["p1", "p1", "", "p2", "", "p2"], 6)
    assert labels.tolist() == [0, 0, 1, 2, 3, 2]


def test_no_shared_label_is_no_groups():
    assert group_labels(["", "", "a", "b"], 4) is None
    assert group_labels(None, 4) is None


def test_wrong_count_of_labels_is_refused():
    with pytest.raises(ValueError, match="3 group labels for 4 fiducials"):
        group_labels(["a", "a", "b"], 4)


def test_merge_joins_sets_across_groups():
    labels = group_labels(["a", "a", "b", "c"], 4)
    assert merge_labels(labels, [[1, 2]], 4).tolist() == [0, 0, 0, 1]
    assert merge_labels(None, [], 4) is None


def test_weighted_quantile_without_groups_is_the_conformal_rank():
    rng = np.random.default_rng(0)
    for n in (5, 19, 20, 60, 277):
        v = rng.exponential(size=n)
        rank = min(n, int(np.ceil(0.95 * (n + 1))))
        assert weighted_quantile(v, 0.95) == np.sort(v)[rank - 1]


def test_weighted_quantile_weighs_every_group_alike():
    # one big group of small values and 19 singletons of larger ones: by group, the big
    # group is one of 20, so the 95 % quantile is among the singletons' largest
    values = np.r_[np.zeros(80), np.arange(1, 20)]
    labels = np.r_[np.zeros(80, dtype=np.intp), np.arange(1, 20)]
    assert weighted_quantile(values, 0.95, labels) == 19.0
    assert weighted_quantile(values, 0.95) < 19.0


def test_paired_test_counts_groups_not_fiducials():
    # four groups of 30 equal errors: per fiducial 120 "wins" would be significant, per group
    # four units cannot be
    u = np.repeat([1.0, 1.0, 1.0, 1.0], 30)
    m = u - 0.1
    labels = np.repeat(np.arange(4), 30)
    assert paired_test(u.copy(), m.copy())[1] < 1e-10
    assert paired_test(u.copy(), m.copy(), units=labels)[1] > 0.05
    assert unit_means(u, labels).shape == (4,)


def test_conformal_quantile_is_the_weighted_one():
    v = np.arange(40.0)
    assert conformal_quantile(v) == weighted_quantile(v, 0.95)


def test_folds_hold_whole_groups_out():
    cell = make_robot_cell(0, poses=12)
    labels = group_labels(cell.fiducial_groups, len(cell.fiducial_ids))
    folds = fold_groups(cell.working, fold_scheme(12), cell.destination, labels)
    assert len(folds) == 12
    for fold in folds:
        assert len({cell.fiducial_groups[k] for k in fold}) == 1
    ten = fold_groups(cell.working, fold_scheme(500), cell.destination, labels)
    for fold in ten:                        # k-fold: every group in one fold
        for g in {cell.fiducial_groups[k] for k in fold}:
            members = [k for k, h in enumerate(cell.fiducial_groups) if h == g]
            assert set(members) <= set(fold.tolist())


def test_cross_validation_with_groups_says_so():
    cell = make_robot_cell(1, poses=20)
    labels = group_labels(cell.fiducial_groups, len(cell.fiducial_ids))
    cv = cross_validate(cell.working, cell.destination, ("uncorrected", "paper"), groups=labels)
    assert cv.scheme.grouped and cv.scheme.n_folds == 20 and cv.n_units == 20
    assert cv.scheme.describe() == "leave-one-group-out (20 folds)"
    plain = cross_validate(cell.working, cell.destination, ("uncorrected", "paper"))
    assert not plain.scheme.grouped and plain.units is None


def test_without_groups_the_model_is_todays():
    cell = make_robot_cell(2, poses=16)
    a = build_model(cell.working, cell.destination, ModelConfig(dimension=3))
    b = build_model(cell.working, cell.destination, ModelConfig(dimension=3),
                    groups=[""] * len(cell.working))
    assert b.groups is None
    assert a.decision.method == b.decision.method
    np.testing.assert_array_equal(a.answer(cell.target_working).tre_bound,
                                  b.answer(cell.target_working).tre_bound)


def test_groups_change_the_held_out_errors_of_a_grouped_cell():
    cell = make_robot_cell(3, poses=24)
    grouped = build_model(cell.working, cell.destination, ModelConfig(dimension=3),
                          ids=cell.fiducial_ids, groups=cell.fiducial_groups)
    assert grouped.groups == cell.fiducial_groups
    assert "groups, each held out whole" in grouped.decision.reason
    assert grouped.decision.to_dict()["folds"]["grouped"] is True


def test_three_groups_are_the_least_to_cross_validate():
    cell = make_robot_cell(4, poses=2)
    labels = group_labels(cell.fiducial_groups, len(cell.fiducial_ids))
    cv = cross_validate(cell.working, cell.destination, ("uncorrected",), groups=labels)
    assert "at least 3 groups" in cv.unavailable["uncorrected"]


def test_ids_of_one_pose_are_named():
    cell = make_robot_cell(5, poses=20)
    line = undeclared_groups(cell.fiducial_ids, cell.working)
    assert "named as points of one pose" in line and "`group`" in line


def test_one_stamp_per_pose_is_named():
    cell = make_robot_cell(6, poses=20)
    stamps = [float(g[4:]) + 1.0 for g in cell.fiducial_groups]     # one stamp per pose
    ids = [f"F{k}" for k in range(len(stamps))]
    assert "measured at one stamp" in undeclared_groups(ids, cell.working, stamps)


def test_a_plate_row_is_no_pose():
    holes = np.stack(np.meshgrid(np.arange(17) * 25.0, np.arange(21) * 25.0,
                                 indexing="ij"), -1).reshape(-1, 2)
    ids = [f"H{r:02d}-{c:02d}" for r in range(17) for c in range(21)]
    assert undeclared_groups(ids, holes) == ""


def test_one_stamp_on_every_point_is_a_clock_not_poses():
    cell = make_robot_cell(7, poses=20)
    assert undeclared_groups([f"F{k}" for k in range(len(cell.working))], cell.working,
                             [5.0] * len(cell.working)) == ""


def test_plain_ids_and_unstamped_points_give_nothing():
    cell = make_robot_cell(8, poses=20)
    ids = [f"F{k:03d}" for k in range(len(cell.working))]
    assert undeclared_groups(ids, cell.working, [0.0] * len(ids)) == ""
