"""The measurement planner (issue 13): expected error, ranking, stopping rule, validation."""

import dataclasses
import types

import numpy as np
import pytest
import scipy.special
from hypothesis import given, settings, strategies as st
from scipy.spatial.transform import Rotation

from rbc_registration.core import ModelConfig, build_model
from rbc_registration.core.constants import DecisionMode
from rbc_registration.core.planning.expected_error import (BiasPosterior, ExpectedErrorModel,
                                                  expected_squared_errors, pooled_median)
from rbc_registration.core.interpolation.kriging import KrigingHyperparameters, KrigingInterpolator
from rbc_registration.core.planning.model_planner import (calibrated, check_expected_error,
                                                 decisive_candidate,
                                                 error_model_from, expected_target_error,
                                                 plan_from_model)
from rbc_registration.core.planning.planner import (PlanConfig, measurement_repeats, overlap_notes,
                                                    plan,
                                           unresolved_bias, work_volume)
from rbc_registration.core.rigid.registration import rigid_fit
from rbc_registration.core.planning.rigid_tre import rigid_tre_covariance
from rbc_registration.core.synthetic.cells import make_cell


def grid(n, lo, hi, d):
    axes = [np.linspace(lo, hi, n)] * d
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, d)


def model(d, noise=0.02, length=1.5, corrected=True):
    return ExpectedErrorModel.from_axis_std(1.0, length, np.full(d, noise), corrected)


def crowded(d):
    """Fiducials fill one corner of [0, 4]^d; the far corner is empty."""
    corners = grid(2, 0.0, 4.0, d)
    return np.vstack([grid(3, 0.0, 2.0, d), corners[1:-1]])


@pytest.mark.parametrize("d", [2, 3])
def test_prefers_a_big_empty_region_to_a_spot_next_to_fiducials(d):
    x = crowded(d)
    near, empty, corner = np.full(d, 1.05), np.full(d, 3.0), np.full(d, 4.0)
    for targets in (None, grid(5, 0.0, 4.0, d)):      # the work volume is the whole [0, 4]^d
        p = plan(x, [near, empty, corner], model(d), targets)
        assert p.sequence == (1,) and list(p.ranking) == [1, 2, 0]
        assert p.gains[1] > 5 * p.gains[0] > 0


@pytest.mark.parametrize("d", [2, 3])
def test_a_candidate_on_an_existing_fiducial_gains_about_nothing(d):
    x = crowded(d)
    p = plan(x, [x[4], np.full(d, 3.0)], model(d, noise=0.01), grid(5, 0.0, 4.0, d))
    assert p.gains[1] > 0.05 * p.expected_now
    assert abs(p.gains[0]) < 1e-3 * p.expected_now


def rigid_motion(d, seed):
    rng = np.random.default_rng(seed)
    if d == 2:
        a = rng.uniform(-np.pi, np.pi)
        r = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    else:
        r = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    return r, rng.normal(scale=100.0, size=d)


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("corrected", [True, False])
def test_rigid_motion_of_the_working_frame_changes_nothing(d, corrected):
    rng = np.random.default_rng(d)
    x, c, t = rng.uniform(0, 4, (12, d)), rng.uniform(0, 4, (30, d)), rng.uniform(0, 4, (9, d))
    std = np.array([0.05, 0.01, 0.03])[:d]          # anisotropic: the covariance moves along
    em = ExpectedErrorModel.from_axis_std(0.5, 2.0, std, corrected)
    base = plan(x, c, em, t, count=4)
    r, shift = rigid_motion(d, 7)
    moved = ExpectedErrorModel(0.5, 2.0, r @ em.noise_covariance @ r.T, corrected)
    p = plan(x @ r.T + shift, c @ r.T + shift, moved, t @ r.T + shift, count=4)
    assert p.sequence == base.sequence
    np.testing.assert_allclose(p.gains, base.gains, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(p.expected_after, base.expected_after, rtol=1e-9)
    # the work volume is an axis-aligned grid: a translation moves it along exactly
    wv = plan(x, c, em, count=2)
    wv_moved = plan(x + shift, c + shift, em, count=2)
    assert wv_moved.sequence == wv.sequence
    np.testing.assert_allclose(wv_moved.gains, wv.gains, rtol=1e-6, atol=1e-12)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2 ** 31 - 1), st.sampled_from([2, 3]))
def test_property_rigid_motion_and_candidate_order_change_no_gain(seed, d):
    rng = np.random.default_rng(seed)
    x, c, t = rng.uniform(0, 4, (9, d)), rng.uniform(0, 4, (20, d)), rng.uniform(0, 4, (5, d))
    em = ExpectedErrorModel.from_axis_std(0.5, 2.0, rng.uniform(0.01, 0.1, d))
    base = plan(x, c, em, t)
    r, shift = rigid_motion(d, seed)
    perm = rng.permutation(len(c))
    moved = ExpectedErrorModel(0.5, 2.0, r @ em.noise_covariance @ r.T)
    p = plan(x @ r.T + shift, c[perm] @ r.T + shift, moved, t @ r.T + shift)
    np.testing.assert_allclose(p.gains, base.gains[perm], rtol=1e-6, atol=1e-12)
    assert p.expected_now == pytest.approx(base.expected_now, rel=1e-9)


def test_permuting_candidates_permutes_the_answer():
    rng = np.random.default_rng(3)
    x, c = rng.uniform(0, 4, (10, 3)), rng.uniform(0, 4, (40, 3))
    perm = rng.permutation(len(c))
    for targets in (None, rng.uniform(0, 4, (7, 3))):
        a = plan(x, c, model(3), targets, count=5)
        b = plan(x, c[perm], model(3), targets, count=5)
        np.testing.assert_allclose(b.gains, a.gains[perm], rtol=1e-9, atol=1e-14)
        assert tuple(perm[list(b.sequence)]) == a.sequence
        np.testing.assert_allclose(b.expected_after, a.expected_after, rtol=1e-10)


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("corrected", [True, False])
def test_greedy_updates_agree_with_planning_again_from_scratch(d, corrected):
    rng = np.random.default_rng(11)
    x, c, t = rng.uniform(0, 4, (8, d)), rng.uniform(0, 4, (25, d)), rng.uniform(0, 4, (6, d))
    em = ExpectedErrorModel.from_axis_std(0.8, 1.5, np.array([0.05, 0.02, 0.03])[:d], corrected)
    # repeats and candidate repeats enter as noise / n
    reps = rng.integers(1, 4, len(x))
    cfg = PlanConfig(candidate_repeats=2, target_repeats=1)
    p = plan(x, c, em, t, count=6, repeats=reps, config=cfg)
    for i in range(6):
        more = np.vstack([x, c[list(p.sequence[:i + 1])]])
        n = np.concatenate([reps, np.full(i + 1, 2)])
        e = expected_squared_errors(more, t, em, n)
        assert pooled_median(e, d) == pytest.approx(p.expected_after[i], rel=1e-9)
        if i + 1 < 6:
            assert p.expected_after[i + 1] < p.expected_after[i]
    # measuring every candidate, in whatever order, ends where expected_with_all says
    every = plan(x, c, em, t, count=len(c), repeats=reps, config=cfg)
    assert every.expected_after[-1] == pytest.approx(p.expected_with_all, rel=1e-9)
    assert "expected with all 25 candidates measured" in p.reason


def test_points_are_planned_as_often_measured_as_the_fiducials_were():
    """fiducials averaged over 200 measurements were planned as if each new fiducial
    and each target were measured once; the target's own noise then dominated the expected error
    (4x the truth on a B-like cell) and every suggestion had a negative gain."""
    rng = np.random.default_rng(3)
    x, c, t = rng.uniform(0, 4, (12, 3)), rng.uniform(0, 4, (30, 3)), rng.uniform(0, 4, (8, 3))
    em = ExpectedErrorModel.from_axis_std(0.05, 3.0, [0.1, 0.1, 0.1])
    reps = np.full(len(x), 200)
    assert measurement_repeats(PlanConfig(), reps) == (200, 200)
    assert measurement_repeats(PlanConfig(), [1, 3, 5]) == (3, 3)
    assert measurement_repeats(PlanConfig(), None) == (1, 1)
    assert measurement_repeats(PlanConfig(candidate_repeats=4), reps) == (4, 200)
    p = plan(x, c, em, t, count=3, repeats=reps)
    assert (p.candidate_repeats, p.target_repeats) == (200, 200)
    explicit = plan(x, c, em, t, count=3, repeats=reps,
                    config=PlanConfig(candidate_repeats=200, target_repeats=200))
    assert p.expected_after == explicit.expected_after and p.expected_now == explicit.expected_now
    once = plan(x, c, em, t, count=3, repeats=reps,
                config=PlanConfig(candidate_repeats=1, target_repeats=1))
    assert min(once.gains) < 0 < min(p.gains)         # a single noisy point would hurt here
    assert p.expected_now < 0.5 * once.expected_now


@pytest.mark.parametrize("where", ["candidates", "targets"])
def test_a_point_far_outside_the_fiducials_is_refused(where):
    """One typo'd candidate 1e6 away became the first suggestion and stretched the work volume
    (the expected error "now" went from 0.1 to 29)."""
    rng = np.random.default_rng(4)
    x, c, t = rng.uniform(0, 500, (10, 2)), rng.uniform(0, 500, (9, 2)), rng.uniform(0, 500, (5, 2))
    em = ExpectedErrorModel.from_axis_std(0.1, 300.0, [0.05, 0.05])
    plan(x, np.vstack([c, [[4000.0, 250.0]]]), em, t)     # 7 sizes out: a cell extended, kept
    far = np.vstack([c if where == "candidates" else t, [[1e6, 0.0]]])
    args = (far, t) if where == "candidates" else (c, far)
    with pytest.raises(ValueError, match=rf"{where[:-1]} {len(far) - 1} \(1e\+06, 0\) is "
                                         r"[\d.e+]+ from the centre of the points, more than "
                                         r"10 x their typical distance .*another unit"):
        plan(x, args[0], em, args[1])



@pytest.mark.parametrize("shift", [3.5, 14.0])
def test_candidates_in_another_frame_or_origin_are_refused(shift):
    """the holes shifted by `shift` cell sizes (another frame or origin) passed
    check_near, since the candidates set its centre, and were planned with meaningless gains;
    with targets, the (right) targets were the ones refused."""
    rng = np.random.default_rng(6)
    holes = grid(12, 0, 500, 2)
    fid = holes[rng.choice(len(holes), 15, replace=False)]
    em = ExpectedErrorModel.from_axis_std(0.1, 300.0, [0.05, 0.05])
    plan(fid, holes, em)                                     # the same holes unshifted: planned
    moved = holes + shift * 500.0
    for targets in (None, rng.uniform(0, 500, (20, 2))):
        with pytest.raises(ValueError, match=r"^the candidates lie [\d.e+]+ beyond the "
                                             r"fiducials' box, more than 2 x the fiducials' "
                                             r"size .*another frame, origin or unit"):
            plan(fid, moved, em, targets)


def test_candidates_away_from_a_measured_patch_are_planned():
    """fiducials in a patch of a plate (its centre, a corner), or on
    one of two parallel rails, with candidates only elsewhere on the plate or the other rail,
    are sound plans."""
    em = ExpectedErrorModel.from_axis_std(0.1, 300.0, [0.05, 0.05])
    patch = grid(3, 0, 100, 2)
    plate = grid(11, -450, 550, 2)
    edges = plate[(np.abs(plate - 50) > 400).any(axis=1)]
    plan(patch, edges, em)                                     # patch at the plate's centre
    corner, holes = grid(3, 0, 100, 2), grid(11, 0, 1000, 2)
    plan(corner, holes[np.linalg.norm(holes, axis=1) > 500], em)   # the plate away from a corner
    rail = np.column_stack([np.linspace(0, 2000, 9), np.zeros(9)])
    rail[:, 1] += np.array([0, 3, -2, 1, 0, -1, 2, -3, 0.0])   # not collinear
    plan(rail, rail + [0.0, 1200.0], em)                       # a parallel rail 1.2 m away


def test_targets_in_another_unit_are_refused_even_when_they_outnumber_the_rest():
    """4 fiducials and 12 candidates in m, 80 targets in mm: the targets set the
    median of all points, and the plan was served."""
    rng = np.random.default_rng(2)
    x, c = rng.uniform(0, 0.5, (4, 2)), rng.uniform(0, 0.5, (12, 2))
    em = ExpectedErrorModel.from_axis_std(1e-4, 0.3, [5e-5, 5e-5])
    with pytest.raises(ValueError, match=r"^target \d+ .* more than 10 x their typical"):
        plan(x, c, em, rng.uniform(0, 500, (80, 2)))


def test_a_cell_started_from_a_few_neighbouring_fiducials_is_planned_over_its_plate():
    """4 neighbouring corner holes (46 mm) and the other 273 holes as candidates were
    refused as "far" when the limit was 10 x the fiducials' own size."""
    holes = np.stack(np.meshgrid(np.arange(17) * 25.0, np.arange(21) * 25.0, indexing="ij"),
                     -1).reshape(-1, 2)
    start = np.array([0, 1, 21, 22])                     # a 25 mm square in one corner
    rest = np.delete(holes, start, axis=0)
    em = ExpectedErrorModel.from_axis_std(0.1, 300.0, [0.05, 0.05])
    p = plan(holes[start] + [[0, 0], [0, 0.1], [0.1, 0], [0, 0]], rest, em, count=1)
    assert np.linalg.norm(rest[p.sequence[0]]) > 300          # far from the start: spread out


def test_a_plan_too_large_for_memory_is_refused(monkeypatch):
    """12,000 candidates x 12,000 targets needed ~14 GB and ended in a MemoryError traceback."""
    import rbc_registration.core.planning.planner as planner
    monkeypatch.setattr(planner, "MAX_CANDIDATE_POINTS", 50)
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 1, (8, 2))
    em = ExpectedErrorModel.from_axis_std(0.1, 0.5, [0.01, 0.01])
    plan(x, rng.uniform(0, 1, (10, 2)), em, rng.uniform(0, 1, (5, 2)))         # 50: planned
    with pytest.raises(ValueError, match=r"^11 candidates x 5 targets = 55 is more than one plan "
                                         r"holds \(50\): give fewer"):
        plan(x, rng.uniform(0, 1, (11, 2)), em, rng.uniform(0, 1, (5, 2)))


def test_gain_decreases_as_fiducials_are_added():
    rng = np.random.default_rng(5)
    pool = rng.uniform(0, 10, (200, 2))
    targets = rng.uniform(1, 9, (20, 2))
    em = ExpectedErrorModel.from_axis_std(1.0, 4.0, [0.05, 0.05])
    best, now = [], []
    for j in (6, 12, 25, 50, 100):
        p = plan(pool[:j], pool[j:], em, targets)
        best.append(p.gains.max())
        now.append(p.expected_now)
    assert np.all(np.diff(best) < 0) and np.all(np.diff(now) < 0)
    p = plan(pool[:6], pool[6:], em, targets, count=30)
    steps = -np.diff(p.error_curve[1])
    assert np.all(steps > 0) and steps[-5:].mean() < 0.2 * steps[:5].mean()


def test_uncorrected_prefers_the_long_lever_arm():
    """Noise only (paper section 6): a fiducial far from the centroid fixes the rotation best."""
    x = grid(3, -1.0, 1.0, 2)
    em = ExpectedErrorModel.from_axis_std(1e-6, 1.0, [0.1, 0.1], corrected=False)
    p = plan(x, [[0.5, 0.2], [6.0, 0.0]], em, [[8.0, 0.0]])
    assert p.sequence == (1,) and p.gains[1] > 3 * p.gains[0] > 0


def test_bias_posterior_is_the_kriging_posterior():
    rng = np.random.default_rng(2)
    x, t = rng.uniform(0, 3, (30, 3)), rng.uniform(-1, 4, (15, 3))
    n = rng.integers(1, 5, 30)
    hyper = KrigingHyperparameters(0.7, 1.3, 0.09, False)
    k = KrigingInterpolator(x, rng.normal(size=x.shape), 0.09, n, hyper)(t)
    em = ExpectedErrorModel.from_axis_std(0.7, 1.3, np.full(3, 0.09 / np.sqrt(3)))
    got = BiasPosterior(x, 1.0 / n, x[:0], 1.0, t, em).now()
    np.testing.assert_allclose(got, 3 * k.expected_error ** 2, rtol=1e-8)


@pytest.mark.parametrize("d", [2, 3])
def test_isotropic_rigid_part_is_fitzpatrick_and_west(d):
    rng = np.random.default_rng(d)
    x = rng.normal(size=(9, d)) * np.array([3.0, 1.5, 0.7])[:d]
    t = rng.uniform(-5, 5, (6, d))
    fle2 = 0.04
    got = np.trace(rigid_tre_covariance(x, t, np.eye(d) * fle2 / d), axis1=1, axis2=2)
    c = x - x.mean(axis=0)
    r = t - x.mean(axis=0)
    if d == 2:
        want = fle2 / len(x) * (1 + np.sum(r * r, 1) / (2 * np.mean(np.sum(c * c, 1))))
    else:
        _, _, vt = np.linalg.svd(c)
        cp, rp = c @ vt.T, r @ vt.T                   # principal axes
        f2 = np.array([np.mean(np.sum(np.delete(cp, k, 1) ** 2, 1)) for k in range(3)])
        d2 = np.array([np.sum(np.delete(rp, k, 1) ** 2, 1) for k in range(3)]).T
        want = fle2 / len(x) * (1 + np.sum(d2 / f2, axis=1) / 3)
    np.testing.assert_allclose(got, want, rtol=1e-10)


@pytest.mark.parametrize("d", [2, 3])
def test_anisotropic_propagation_matches_monte_carlo_rigid_fits(d):
    rng = np.random.default_rng(100 + d)
    x = rng.uniform(-1, 1, (8, d)) * np.array([3.0, 1.0, 0.5])[:d]
    r, shift = rigid_motion(d, 1)
    y = x @ r.T + shift
    targets = rng.uniform(-2, 2, (5, d))
    std = np.array([0.05, 0.01, 0.03])[:d]
    n = rng.integers(1, 4, len(x))                    # repeats: noise Sigma / n_j per fiducial
    cov = np.diag(std ** 2)[None] / n[:, None, None]
    want = rigid_tre_covariance(x, targets, cov)
    trials = 2000
    err = np.empty((trials, len(targets), d))
    for k in range(trials):
        noisy = x + rng.normal(size=x.shape) * std / np.sqrt(n)[:, None]
        fit = rigid_fit(noisy, y)
        err[k] = (fit.apply(targets) - (targets @ r.T + shift)) @ r   # working-frame axes
    mc = np.einsum("nka,nkb->kab", err, err) / trials
    tr_want, tr_mc = np.trace(want, axis1=1, axis2=2), np.trace(mc, axis1=1, axis2=2)
    np.testing.assert_allclose(tr_mc, tr_want, rtol=0.10)
    np.testing.assert_allclose(np.diagonal(mc, axis1=1, axis2=2),
                               np.diagonal(want, axis1=1, axis2=2), rtol=0.15)
    # the anisotropy is real: isotropic noise of the same total predicts something else
    iso = rigid_tre_covariance(x, targets, np.eye(d) * np.sum(std ** 2) / d / n[:, None, None])
    assert np.max(np.abs(np.trace(iso, axis1=1, axis2=2) / tr_want - 1)) > 0.2


def test_pooled_median_is_the_median_of_the_pooled_errors():
    rng = np.random.default_rng(4)
    for d in (2, 3):
        e = rng.uniform(0.1, 3.0, 12) ** 2
        assert pooled_median(np.full(5, 2.0), d) == pytest.approx(
            np.median(np.linalg.norm(rng.normal(size=(200000, d)), axis=1)) * np.sqrt(2.0 / d),
            rel=5e-3)
        draws = rng.normal(size=(40000, 12, d)) * np.sqrt(e / d)[None, :, None]
        assert pooled_median(e, d) == pytest.approx(
            np.median(np.linalg.norm(draws, axis=2)), rel=5e-3)
        # a batch of rows spanning decades: each row's pooled CDF is 1/2 at its median
        rows = np.exp(rng.uniform(-12, 2, (300, 9)))
        m = pooled_median(rows, d)
        cdf = scipy.special.gammainc(d / 2, d * m[:, None] ** 2 / (2 * rows)).mean(axis=1)
        np.testing.assert_allclose(cdf, 0.5, atol=1e-12)


def test_stopping_rule():
    """The gain rule (min_gain_fraction 2 %, within off) and the default within rule."""
    rng = np.random.default_rng(8)
    pool = rng.uniform(0, 10, (300, 2))
    t = rng.uniform(0, 10, (10, 2))
    em = ExpectedErrorModel.from_axis_std(1.0, 4.0, [0.05, 0.05])
    by_gain = PlanConfig(min_gain_fraction=0.02, within=0.0)
    sparse = plan(pool[:6], pool[6:], em, t, count=40, config=by_gain)
    assert not sparse.enough and sparse.reason.startswith("measure more")
    assert sparse.enough_after is not None and 0 < sparse.enough_after < 40
    k = sparse.enough_after
    # measuring the suggestions up to there makes the plan say enough
    more = np.vstack([pool[:6], pool[6:][list(sparse.sequence[:k])]])
    rest = np.delete(pool[6:], list(sparse.sequence[:k]), axis=0)
    done = plan(more, rest, em, t, config=by_gain)
    assert done.enough and done.reason.startswith("enough") and "2 %" in done.reason
    assert done.enough_after == 0 and done.enough_rule == "gain"
    assert done.gains.max() < 0.02 * done.expected_now
    # a length threshold stops earlier; no rule never stops
    by_length = plan(pool[:6], pool[6:], em, t, config=PlanConfig(min_gain_length=1e3))
    assert by_length.enough and "1000" in by_length.reason
    never = plan(more, rest, em, t, config=PlanConfig(min_gain_fraction=0.0, within=0.0))
    assert not never.enough
    # the default: within 10 % of the error with every candidate measured
    default = plan(pool[:6], pool[6:], em, t, count=60)
    assert not default.enough and default.expected_now > 1.1 * default.expected_with_all
    k = default.enough_after
    assert k is not None and default.expected_after[k - 1] <= 1.1 * default.expected_with_all
    assert k == 1 or default.expected_after[k - 2] > 1.1 * default.expected_with_all
    more = np.vstack([pool[:6], pool[6:][list(default.sequence[:k])]])
    rest = np.delete(pool[6:], list(default.sequence[:k]), axis=0)
    close = plan(more, rest, em, t)
    assert close.enough and close.enough_rule == "within" and "within 10 %" in close.reason
    assert close.expected_now <= 1.1 * close.expected_with_all
    assert close.expected_with_all == pytest.approx(default.expected_with_all, rel=1e-9)


@pytest.mark.parametrize("d", [2, 3])
def test_no_enough_while_the_bias_length_scale_is_below_the_fiducial_spacing(d):
    """A fitted length scale shorter than the fiducials' spacing (with a bias above the noise)
    makes every candidate look useless: the plan must not call that enough."""
    x = grid(3, 0.0, 4.0, d)                              # spacing 2
    c = grid(5, 0.0, 4.0, d)
    easy = PlanConfig(min_gain_fraction=0.99)
    short = plan(x, c, model(d, length=0.5), config=easy, count=2)
    assert not short.enough and short.enough_after is None
    assert short.reason.startswith("measure more: the fitted bias length scale (0.5) is shorter "
                                   "than the fiducials' spacing (2)")
    assert unresolved_bias(x, model(d, length=0.5)) in short.reason
    assert plan(x, c, model(d, length=2.0), config=easy).enough       # resolved: spacing
    # a fit with sigma unknown stops at the spacing, to rounding ("189.8 is shorter
    # than the spacing 189.8")
    assert unresolved_bias(x, model(d, length=2.0 * (1 - 1e-12))) is None
    tiny = ExpectedErrorModel.from_axis_std(0.01, 0.5, np.full(d, 0.05))   # bias below noise
    assert unresolved_bias(x, tiny) is None and plan(x, c, tiny, config=easy).enough
    rigid_only = model(d, length=0.5, corrected=False)    # no bias learnt: nothing to resolve
    assert plan(x, c, rigid_only, config=easy).enough
    # exact data: a 'bias' and a noise of rounding (8e-14 against 8e-17) said "measure more"
    exact = ExpectedErrorModel.from_axis_std(1e-14, 0.5, np.full(d, 1e-17))
    assert unresolved_bias(x + 1000.0, exact) is None


def test_the_plan_is_immutable_and_typed():
    x = crowded(2)
    p = plan(x, grid(4, 0.5, 3.5, 2), model(2), count=3)
    with pytest.raises(ValueError):
        p.gains[0] = 1.0
    with pytest.raises(AttributeError):
        p.enough = True
    counts, errors = p.error_curve
    assert list(counts) == [len(x), len(x) + 1, len(x) + 2, len(x) + 3]
    assert errors[0] == p.expected_now and tuple(errors[1:]) == p.expected_after
    assert not p.on_targets and len(p.points) == len(p.expected_point_errors) > 100
    assert p.ranking[0] == p.sequence[0] and len(set(p.sequence)) == 3


def test_work_volume_is_inside_the_hull():
    pts = np.array([[0, 0], [4, 0], [0, 4.0], [1, 1]])
    wv = work_volume(pts, 400)
    assert 150 < len(wv) < 250 and np.all(wv.sum(axis=1) <= 4.0)
    flat = np.column_stack([grid(3, 0, 1, 2), np.zeros(9)])
    np.testing.assert_array_equal(work_volume(flat, 50), flat)
    tri = work_volume(pts[:3], 50)        # d + 1 points are one simplex: the grid inside it
    assert len(tri) > 3 and np.all(tri.sum(axis=1) <= 4.0) and np.all(tri >= 0)



@pytest.mark.parametrize("thickness", [1e-3, 1e-7, 1e-9])
def test_work_volume_of_a_nearly_flat_plate_stays_near_its_count(thickness):
    """A 0.5 m plate whose z spread is rounding: the grid keeps about ``count`` cells inside a
    hull that is not flat (1e-3; below about 1e-5 the hull is flat and the points themselves are
    the work volume). Before, the thin axis made the cell side tiny: 156,057 points at 1e-3 m, a
    MemoryError at 1e-8."""
    rng = np.random.default_rng(5)
    xy = grid(4, 0, 0.5, 2)
    pts = np.column_stack([xy, rng.normal(scale=thickness, size=len(xy))])
    wv = work_volume(pts, 400)
    if thickness >= 1e-3:
        assert 100 < len(wv) <= 2 * 400
    else:
        np.testing.assert_array_equal(wv, pts)
    assert np.all(wv.min(axis=0) >= pts.min(axis=0)) and np.all(wv.max(axis=0) <= pts.max(axis=0))
    cube = grid(2, 0, 0.3, 3)          # count 1: the cube root rounds, every axis "thin"
    assert 1 <= len(work_volume(cube, 1)) <= 8


@pytest.fixture(scope="module")
def ra_model():
    cell = make_cell("RA", seed=1)
    x = np.array([m[0] for m in cell.fiducial_measurements])
    pick = np.random.default_rng(0).permutation(len(x))
    cfg = ModelConfig(dimension=2, interpolation="kriging", sigma=cell.spec.sigma)
    return build_model(x[pick[:40]], cell.fiducial_truth[pick[:40]], cfg), x[pick[40:]], cell


def test_plan_from_a_model(ra_model):
    m, rest, cell = ra_model
    em = error_model_from(m)
    hyper = m.kriging_hyperparameters
    assert em.signal_std == hyper.signal_std and em.corrected
    np.testing.assert_allclose(np.trace(em.noise_covariance), cell.spec.sigma ** 2)
    tw = np.array([t[0] for t in cell.target_measurements])
    p = plan_from_model(m, rest, tw, count=3)
    assert p.on_targets and p.fiducial_count == 40
    assert p.expected_after[-1] < p.expected_now
    # the plan's expected error is the model's, calibrated by the held-out errors
    cal, check = calibrated(m)
    assert p.model_check == check and cal.calibration == check.ratio
    assert expected_target_error(m, tw, error_model=cal) == pytest.approx(p.expected_now,
                                                                          rel=1e-12)
    assert expected_target_error(m, tw, error_model=em) * check.ratio == pytest.approx(
        p.expected_now, rel=1e-12)
    assert 0.5 * p.expected_now < expected_target_error(m) < 2 * p.expected_now
    paper = build_model(m.working, m.destination, ModelConfig(dimension=2, sigma=0.11))
    assert error_model_from(paper).length_scale == pytest.approx(hyper.length_scale, rel=1e-6)


class Decided:
    """A model with the decision of issue 9 (``decision.apply``, ``confident``, ``mode``), for
    the planner's adapter."""

    def __init__(self, model, apply, confident=True, mode=DecisionMode.CV):
        self._model = model
        self.decision = types.SimpleNamespace(apply=apply, confident=confident, mode=mode,
                                              cross_validation=model.decision.cross_validation)

    def __getattr__(self, name):
        return getattr(self._model, name)


def test_the_served_error_follows_the_decision_and_the_plan_assumes_the_correction(ra_model):
    m, rest, _ = ra_model
    assert error_model_from(Decided(m, True), served=True).corrected
    assert not error_model_from(Decided(m, False), served=True).corrected
    assert error_model_from(Decided(m, False)).corrected      # planning: always corrected
    # uncorrected served: the bias stays, so today's expected error is larger ...
    assert expected_target_error(Decided(m, False)) > 2 * expected_target_error(Decided(m, True))
    # ... but the plan is that of the correction more fiducials make possible: the same ranking
    # and gains, not a bias floor that no measurement lowers (which said "enough" at once)
    p_on, p_off = plan_from_model(m, rest, count=3), plan_from_model(Decided(m, False), rest,
                                                                     count=3)
    assert p_off.sequence == p_on.sequence
    np.testing.assert_array_equal(p_off.gains, p_on.gains)
    assert p_off.gains.max() > 0


def test_no_enough_while_the_decision_is_unsure_whether_to_correct(ra_model):
    """The plan assumes the correction; while a cv decision serves the uncorrected registration
    without being confident, enough would stop the user at the uncorrected error."""
    m, rest, _ = ra_model
    easy = PlanConfig(min_gain_fraction=0.99)                # every candidate gains less
    assert plan_from_model(Decided(m, False), rest, config=easy).enough      # confident
    assert plan_from_model(Decided(m, False, False, DecisionMode.RHO), rest, config=easy).enough
    held = plan_from_model(Decided(m, False, confident=False), rest, count=2, config=easy)
    assert not held.enough and held.enough_after is None
    assert held.reason.startswith("measure more: the decision serves the uncorrected")
    assert "enough:" not in held.reason and "rules apply once it is" in held.reason
    base = plan_from_model(m, rest, count=2, config=easy)
    assert held.expected_now == base.expected_now
    np.testing.assert_array_equal(held.gains, base.gains)
    np.testing.assert_array_equal(held.ranking, base.ranking)
    # while unsure, the first suggestion tests the correction: the largest |eps| / its spread
    k, z = decisive_candidate(m, rest)
    out = m.interpolators["kriging"](rest)
    score = np.linalg.norm(out.correction, axis=1) / out.expected_error
    assert k == int(np.argmax(score)) and z == pytest.approx(score.max())
    assert held.sequence[0] == k != base.sequence[0] and f"(#{k})" in held.reason
    assert held.expected_after[0] == pytest.approx(base.expected_now - base.gains[k], rel=1e-9)
    forced = plan(m.working, rest, calibrated(m)[0], count=2, repeats=m.counts, config=easy,
                  first=k)
    assert forced.sequence == held.sequence               # the rest greedy after it
    assert forced.expected_after == pytest.approx(held.expected_after, rel=1e-12)
    with pytest.raises(ValueError, match="first must be a candidate index"):
        plan(m.working, rest, error_model_from(m), first=len(rest))
    # a real one: RA seed 17, 10 fiducials (the start of benchmarks/plan_cells.py)
    cell = make_cell("RA", seed=17)
    x = np.array([t[0] for t in cell.fiducial_measurements])
    first = np.random.default_rng([17, 13]).permutation(len(x))
    few = build_model(x[first[:10]], cell.fiducial_truth[first[:10]],
                      ModelConfig(dimension=2, interpolation="kriging", sigma=cell.spec.sigma))
    assert not few.decision.apply and not few.decision.confident
    p = plan_from_model(few, x[first[10:]], config=easy)
    assert not p.enough and "not confident" in p.reason


def test_a_decisive_candidate_within_its_noise_is_not_forced_first(ra_model, monkeypatch):
    """a "decisive" candidate at 0.00065 sigma displaced the best-gain one; below
    MIN_DECISIVE_Z the plan is greedy from its first suggestion, and still held back."""
    from rbc_registration.core.planning import model_planner

    m, rest, _ = ra_model
    base = plan_from_model(m, rest, count=2)
    other = int(base.ranking[-1])                         # the worst candidate, if it were forced
    monkeypatch.setattr(model_planner, "held_back_by_decision", lambda model: "unsure")
    for z, first in ((0.5, int(base.ranking[0])), (model_planner.MIN_DECISIVE_Z, other)):
        monkeypatch.setattr(model_planner, "decisive_candidate", lambda model, c, z=z: (other, z))
        held = plan_from_model(m, rest, count=2)
        assert not held.enough and held.sequence[0] == first
        assert ("to test it" in held.reason) == (first == other)


def test_cross_validation_agrees_with_the_expected_error(ra_model):
    m, _, _ = ra_model
    cv = check_expected_error(m)
    assert cv.expected.shape == cv.actual.shape == (40,)
    assert 0.7 < cv.ratio < 1.4
    scaled = check_expected_error(m, dataclasses.replace(error_model_from(m), calibration=2.0))
    assert scaled.expected_median == pytest.approx(2 * cv.expected_median, rel=1e-9)


X3 = crowded(3)
C3 = np.array([[3.0, 3.0, 3.0], [1.0, 2.0, 3.0]])


@pytest.mark.parametrize("args, kwargs, message", [
    pytest.param((np.zeros((5, 4)), C3), {}, r"fiducials must have shape \(N, 3\)", id="shape"),
    pytest.param((X3[:3], C3), {}, "fiducials needs at least 4 points", id="too-few"),
    pytest.param((np.outer(np.arange(6.0), [1, 1, 1]), C3), {}, "collinear", id="collinear"),
    pytest.param((X3, C3[:, :2]), {}, r"candidates must have shape \(N, 3\)", id="dim-mismatch"),
    pytest.param((X3, np.zeros((0, 3))), {}, "candidates needs at least 1", id="no-candidates"),
    pytest.param((X3, [[np.nan, 0, 0]]), {}, "candidates contains NaN", id="nan"),
    pytest.param((X3, C3, [[0, np.inf, 0]]), {}, "targets contains NaN or inf", id="inf"),
    pytest.param((X3, C3, [[0, 0]]), {}, r"targets must have shape \(N, 3\)", id="targets-dim"),
    pytest.param((X3, C3), {"count": 3}, r"count \(3\) exceeds the number of candidates \(2\)",
                 id="count-beyond"),
    pytest.param((X3, C3), {"count": 0}, "count must be a positive integer", id="count-zero"),
    pytest.param((X3, C3), {"repeats": [1, 2]}, "repeats must be 33 counts", id="repeats"),
])
def test_validation(args, kwargs, message):
    x, c, *rest = args
    with pytest.raises(ValueError, match=message):
        plan(x, c, model(3), *rest, **kwargs)


@pytest.mark.parametrize("make, message", [
    pytest.param(lambda: PlanConfig(min_gain_fraction=1.5), "min_gain_fraction", id="fraction"),
    pytest.param(lambda: PlanConfig(min_gain_length=-1), "min_gain_length", id="length"),
    pytest.param(lambda: PlanConfig(work_volume_points=0), "work_volume_points", id="volume"),
    pytest.param(lambda: PlanConfig(candidate_repeats=1.5), "candidate_repeats", id="repeats"),
    pytest.param(lambda: ExpectedErrorModel(0.0, 1.0, np.eye(2)), "signal_std", id="signal"),
    pytest.param(lambda: ExpectedErrorModel(1.0, np.nan, np.eye(2)), "length_scale",
                 id="length-nan"),
    pytest.param(lambda: ExpectedErrorModel(1.0, 1.0, np.eye(4)), r"shape \(2, 2\) or \(3, 3\)",
                 id="cov-shape"),
    pytest.param(lambda: ExpectedErrorModel(1.0, 1.0, [[1, 0.5], [0, 1]]), "symmetric", id="asym"),
    pytest.param(lambda: ExpectedErrorModel(1.0, 1.0, -np.eye(3)), "semi-definite", id="negative"),
    pytest.param(lambda: ExpectedErrorModel.from_axis_std(1.0, 1.0, [0.1, -0.1]), "axis_std",
                 id="axis-std"),
])
def test_config_validation(make, message):
    with pytest.raises(ValueError, match=message):
        make()


@pytest.mark.parametrize("d", [2, 3])
def test_a_far_point_does_not_make_the_fit_look_degenerate(d):
    """G with a point 1e9 units out has rows of very different size: its plain condition
    number said "cannot fix a rigid registration"; conditioned on its diagonal it is fine."""
    from rbc_registration.core.planning.rigid_tre import RigidFitError
    rng = np.random.default_rng(d)
    x = rng.uniform(0, 1, (12, d))
    far = np.zeros((1, d))
    far[0, 0] = 1e9
    cov = np.eye(d) * 1e-4
    fit = RigidFitError(np.vstack([x, far]), cov, x[:2], cov, x[:3])
    assert np.all(np.isfinite(fit.now())) and np.all(fit.now() > 0)
    np.testing.assert_allclose(rigid_tre_covariance(x, x[:3], cov),
                               rigid_tre_covariance(x + 1e6, x[:3] + 1e6, cov), rtol=1e-6)


def test_candidates_that_look_like_a_mix_up_of_the_files_are_named():
    """candidate ids that are fiducial ids at another place, and the fiducials file
    given as the candidates, were planned without a word."""
    holes = grid(6, 0.0, 500.0, 2)
    ids = [f"H{k}" for k in range(len(holes))]
    fid, fid_ids = holes[:10], ids[:10]
    assert overlap_notes(fid, fid_ids, holes[10:], ids[10:]) == []
    moved = overlap_notes(fid, fid_ids, holes[10:14], ["H0", "H1", "X", "Y"])
    assert moved == ["2 candidate id(s) are fiducial ids at another place ('H0', 'H1'): a mix-up "
                     "between the files? They are planned as new locations"]
    again = overlap_notes(fid, fid_ids, np.vstack([holes[10:], fid[3:4] + 0.1]),
                          ids[10:] + ["again"])
    assert again == ["1 of 27 candidates are at measured fiducials (within 1 % of their spacing, "
                     "e.g. 'again'): measuring one again only averages its noise"]
    same = overlap_notes(fid, fid_ids, fid, fid_ids)           # the fiducials as candidates
    assert len(same) == 1 and same[0].startswith("10 of 10 candidates are at measured fiducials")


@pytest.mark.parametrize("d", [2, 3])
@pytest.mark.parametrize("corrected", [True, False])
def test_a_group_is_planned_as_its_candidates_measured_together(d, corrected):
    """Groups (one robot pose measures several candidates): each step's expected error is that
    of planning again from scratch with every candidate of the chosen groups measured."""
    rng = np.random.default_rng(21)
    x, c, t = rng.uniform(0, 4, (8, d)), rng.uniform(0, 4, (24, d)), rng.uniform(0, 4, (6, d))
    em = ExpectedErrorModel.from_axis_std(0.8, 1.5, np.array([0.05, 0.02, 0.03])[:d], corrected)
    labels = [f"pose{k % 8}" for k in range(len(c))]          # 8 poses of 3, interleaved
    p = plan(x, c, em, t, count=4, groups=labels)
    assert p.unit_labels == tuple(f"pose{k}" for k in range(8))
    assert p.members == tuple(tuple(range(k, 24, 8)) for k in range(8))
    assert len(p.gains) == len(p.ranking) == 8
    for i in range(4):
        taken = [m for u in p.sequence[:i + 1] for m in p.members[u]]
        e = expected_squared_errors(np.vstack([x, c[taken]]), t, em)
        assert pooled_median(e, d) == pytest.approx(p.expected_after[i], rel=1e-9)
    # each group's gain: measured alone next, all its candidates
    for u in range(8):
        e = expected_squared_errors(np.vstack([x, c[list(p.members[u])]]), t, em)
        assert p.expected_now - pooled_median(e, d) == pytest.approx(p.gains[u], rel=1e-7,
                                                                     abs=1e-12)
    assert p.sequence[0] == int(np.argmax(p.gains)) == p.ranking[0]
    assert p.ranked_candidates == tuple(m for u in p.sequence for m in p.members[u])
    counts, _ = p.error_curve
    assert list(counts) == [8, 11, 14, 17, 20]
    by_gain = plan(x, c, em, t, groups=labels, config=PlanConfig(within=0.0,
                                                                min_gain_fraction=0.5))
    assert by_gain.reason.startswith("enough: the best next group "
                                     f"{p.unit_labels[p.sequence[0]]!r} is expected to reduce")


def test_candidates_without_a_group_label_are_their_own_units():
    rng = np.random.default_rng(4)
    x, c = rng.uniform(0, 4, (8, 2)), rng.uniform(0, 4, (10, 2))
    em = model(2)
    alone = plan(x, c, em, count=3)
    same = plan(x, c, em, count=3, groups=[""] * len(c))
    assert same.sequence == alone.sequence and same.unit_labels == ("",) * 10
    np.testing.assert_allclose(same.gains, alone.gains, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(same.expected_after, alone.expected_after, rtol=1e-9)
    mixed = plan(x, c, em, count=2, groups=["a", "a"] + [""] * 8)
    assert mixed.members[0] == (0, 1) and len(mixed.members) == 9
    with pytest.raises(ValueError, match="got 3 candidate group labels for 10 candidates"):
        plan(x, c, em, groups=["a", "b", "c"])
    with pytest.raises(ValueError, match=r"count \(3\) exceeds the number of candidate groups "
                                         r"\(2\)"):
        plan(x, c, em, count=3, groups=["a"] * 5 + ["b"] * 5)
