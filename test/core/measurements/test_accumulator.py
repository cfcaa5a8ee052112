"""Tests of the pure fiducial accumulator (no rclpy)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rbc_registration.core.measurements.accumulator import (REJECT_REASONS, EnabledChange,
                                                            FiducialAccumulator,
                                               Measurement, RejectedMeasurement)


def make(dimension=3, merge_radius=0.005, outlier_distance=0.002):
    return FiducialAccumulator(dimension, "tracker", "world", merge_radius, outlier_distance)


def grid(rng, n=12):
    dest = np.array([[x, y, z] for x in (0.0, 0.1, 0.2) for y in (0.0, 0.1) for z in (0.0, 0.05)])
    return dest[:n], dest[:n] + 1.0 + rng.normal(0, 1e-4, (n, 3))


def test_explicit_ids_repeats_and_means():
    acc = make()
    assert acc.add("a", [0, 0, 0], [1, 1, 1]) == "a"
    assert acc.add("a", [0.001, 0, 0], [1.001, 1, 1]) == "a"
    assert acc.add("b", [0.1, 0, 0], [1.1, 1, 1]) == "b"
    fs = acc.fiducial_set()
    assert fs.ids == ("a", "b")
    np.testing.assert_allclose(fs.working, [[0.0005, 0, 0], [0.1, 0, 0]])
    np.testing.assert_allclose(fs.destination, [[1.0005, 1, 1], [1.1, 1, 1]])
    assert list(fs.repeat_stats.counts) == [2, 1]
    # sigma_j^2: sum over axes of the sample variance of the repeats (NaN for one measurement)
    assert fs.repeat_stats.variances[0] == pytest.approx(np.var([0, 0.001], ddof=1))
    assert np.isnan(fs.repeat_stats.variances[1])
    assert fs.n_measurements == acc.n_measurements == 3


def test_auto_ids_by_proximity_in_destination_frame():
    acc = make(merge_radius=0.005, outlier_distance=0.01)
    first = acc.add(None, [0, 0, 0], [1, 1, 1])
    assert first == "auto-0000"
    # 3 mm away in the destination frame: the same hole, although the working point differs.
    assert acc.add("", [0.001, 0, 0], [1.003, 1, 1]) == first
    assert acc.add(None, [0.1, 0, 0], [1.1, 1, 1]) == "auto-0001"
    # An explicit id is also found by proximity.
    acc.add("H1", [0.2, 0, 0], [1.2, 1, 1])
    assert acc.add(None, [0.2, 0, 0], [1.2, 1.001, 1]) == "H1"
    assert acc.fiducial_set().ids == ("auto-0000", "auto-0001", "H1")
    assert acc.fiducial_set().repeat_stats.counts[0] == 2


def test_auto_id_skips_an_explicit_id_of_the_same_form():
    acc = make()
    acc.add("auto-0000", [0, 0, 0], [1, 1, 1])
    assert acc.add(None, [0.1, 0, 0], [1.1, 1, 1]) == "auto-0001"


def test_dimension_2_uses_x_y_only():
    acc = make(dimension=2)
    acc.add("a", [0, 0, 5.0], [1, 1, -3.0])
    acc.add("a", [0, 0, 9.0], [1, 1, 7.0])   # z differs widely: ignored, not an outlier
    acc.add("b", [0.1, 0.2], [1.1, 1.2])      # 2 coordinates accepted in 2D
    fs = acc.fiducial_set()
    assert fs.working.shape == (2, 2)
    np.testing.assert_allclose(fs.destination, [[1, 1], [1.1, 1.2]])


@pytest.mark.parametrize("kwargs, reason", [
    pytest.param(dict(working_frame="camera"), "frame", id="working-frame"),
    pytest.param(dict(destination_frame="map"), "frame", id="destination-frame"),
    pytest.param(dict(working_xyz=[0, math.nan, 0]), "nonfinite", id="nan"),
    pytest.param(dict(destination_xyz=[0, 0, math.inf]), "nonfinite", id="inf"),
    pytest.param(dict(working_xyz=[0, 0, 1e300]), "nonfinite", id="1e300"),
    pytest.param(dict(working_xyz=[0, 0]), "malformed", id="2-coordinates-in-3d"),
    pytest.param(dict(working_xyz="abc"), "malformed", id="text"),
    pytest.param(dict(fiducial_id=7), "malformed", id="id-not-a-string"),
    pytest.param(dict(fiducial_id="a\nb"), "malformed", id="id-with-line-break"),
    pytest.param(dict(fiducial_id="x" * 2**20), "malformed", id="1MB-id"),
    pytest.param(dict(stamp_s=math.nan), "malformed", id="nan-stamp"),
    pytest.param(dict(stamp_s=1.0, now_s=100.0), "stale", id="old-stamp"),
    pytest.param(dict(stamp_s=1000.0, now_s=100.0), "stale", id="future-stamp"),
])
def test_each_rejection_reason_is_counted_and_nothing_is_added(kwargs, reason):
    acc = make()
    acc.add("a", [0, 0, 0], [1, 1, 1])
    acc.max_stamp_age = 10.0
    args = dict(fiducial_id="a", working_xyz=[0, 0, 0], destination_xyz=[1, 1, 1],
                working_frame="tracker", destination_frame="world", stamp_s=1.0)
    args.update(kwargs)
    before = acc.state_digest()
    with pytest.raises(RejectedMeasurement) as info:
        acc.add(**args)
    assert info.value.reason == reason
    assert info.value.message in str(info.value)
    assert len(info.value.message) < 300    # a 1 MB value is quoted cut short
    assert acc.rejected[reason] == 1 and acc.n_rejected == 1
    assert acc.state_digest() == before and acc.n_measurements == 1


def test_stamp_age_messages_and_limits():
    acc = FiducialAccumulator(3, "tracker", "world", 0.005, 0.0, max_stamp_age=5.0)
    with pytest.raises(RejectedMeasurement, match=r"stamp 100.000 s is 50 s older than the clock "
                                                  r"\(150.000 s\); max_stamp_age is 5 s"):
        acc.prepare("a", [0, 0, 0], [1, 1, 1], stamp_s=100.0, now_s=150.0)
    with pytest.raises(RejectedMeasurement, match="is 3.6e\\+03 s ahead of the clock"):
        acc.prepare("a", [0, 0, 0], [1, 1, 1], stamp_s=3750.0, now_s=150.0)
    for stamp in (145.0, 150.0, 155.0):   # within the age either way: accepted
        acc.commit(acc.prepare("a", [0, 0, 0], [1, 1, 1], stamp_s=stamp, now_s=150.0))
    acc.prepare("a", [0, 0, 0], [1, 1, 1], stamp_s=0.0)   # no clock given: no check
    acc.max_stamp_age = 0.0                                # 0: off
    acc.prepare("a", [0, 0, 0], [1, 1, 1], stamp_s=0.0, now_s=1e9)
    assert acc.rejected["stale"] == 2 and acc.n_measurements == 3


def test_long_values_are_quoted_short():
    acc = make()
    acc.add("a", [0, 0, 0], [1, 1, 1])
    with pytest.raises(RejectedMeasurement, match=r"got 'cccc.*\.\.\. \(1048576 characters\)$"):
        acc.prepare("a", [0, 0, 0], [1, 1, 1], working_frame="c" * 2**20)
    with pytest.raises(KeyError) as info:
        acc.prepare_enabled("z" * 2**20, False)
    assert "(1048576 characters) (known: 'a')" in str(info.value) and len(str(info.value)) < 200


def test_an_unknown_id_names_the_known_ones_quoted():
    """the known ids were listed unquoted ('known: a, b, c' for the ids 'a, b' and
    'c' too) and cut with '...'; now each is quoted and the rest counted."""
    acc = make()
    for k, fid in enumerate(["a, b", "c"] + [f"h{n}" for n in range(25)]):
        acc.add(fid, [k, 0, 0], [k, 1, 1])
    with pytest.raises(KeyError) as info:
        acc.prepare_enabled("zz", False)
    text = str(info.value.args[0])
    assert text.startswith("unknown fiducial id 'zz' (known: 'a, b', 'c', 'h0', ")
    assert text.endswith("'h17' and 7 more)"), text


def test_outlier_in_either_frame_is_rejected():
    acc = make(outlier_distance=0.002)
    acc.add("a", [0, 0, 0], [1, 1, 1])
    with pytest.raises(RejectedMeasurement, match="working point is 0.005"):
        acc.add("a", [0.005, 0, 0], [1, 1, 1])
    with pytest.raises(RejectedMeasurement, match="destination point"):
        acc.add("a", [0, 0, 0], [1, 1, 1.003])
    assert acc.rejected["outlier"] == 2
    acc.add("a", [0.001, 0, 0], [1, 1, 1.001])  # within the distance: a repeat


def test_outlier_check_can_be_disabled():
    acc = make(outlier_distance=0.0)
    acc.add("a", [0, 0, 0], [1, 1, 1])
    acc.add("a", [1, 0, 0], [1, 1, 1])
    assert acc.n_rejected == 0


def test_empty_frames_mean_the_defaults():
    acc = make()
    acc.add("a", [0, 0, 0], [1, 1, 1], "", "")
    acc.add("a", [0, 0, 0], [1, 1, 1], "tracker", "world")
    assert acc.n_measurements == 2


def test_enable_disable():
    acc = make()
    for k in range(4):
        acc.add(f"f{k}", [k * 0.1, 0, 0], [1 + k * 0.1, 1, 1])
    acc.set_enabled("f1", False)
    fs = acc.fiducial_set()
    assert fs.ids == ("f0", "f2", "f3") and fs.disabled_ids == ("f1",)
    acc.add("f1", [0.1, 0, 0], [1.1, 1, 1])  # still collected while disabled
    acc.set_enabled("f1", True)
    assert acc.fiducial_set().ids == ("f0", "f1", "f2", "f3")
    assert acc.fiducial_set().repeat_stats.counts[1] == 2
    with pytest.raises(KeyError, match="unknown fiducial id 'nope'"):
        acc.set_enabled("nope", False)


def test_restore_from_records_gives_identical_state():
    rng = np.random.default_rng(0)
    acc = make(merge_radius=0.01, outlier_distance=0.003)
    dest, work = grid(rng)
    records = []
    for visit in range(3):
        for k in range(len(dest)):
            fid = None if k % 2 else f"H{k}"
            w = work[k] + rng.normal(0, 2e-4, 3)
            d = dest[k] + rng.normal(0, 2e-4, 3)
            rec = acc.prepare(fid, w, d, stamp_s=visit * 100 + k)
            acc.commit(rec)
            records.append(rec)
    with pytest.raises(RejectedMeasurement):
        acc.add("H0", work[0] + 0.1, dest[0])
    change = acc.prepare_enabled("H2", False)
    acc.commit(change)
    records.append(change)
    # Replayed with different merge/outlier parameters: records carry their ids.
    other = FiducialAccumulator(3, "tracker", "world", merge_radius=1e-6, outlier_distance=1e-9)
    other.restore(records)
    assert other.state_digest() == acc.state_digest()
    a, b = acc.fiducial_set(), other.fiducial_set()
    assert a.ids == b.ids and a.disabled_ids == b.disabled_ids == ("H2",)
    np.testing.assert_array_equal(a.working, b.working)
    np.testing.assert_array_equal(a.destination, b.destination)
    # Auto ids continue identically after a restore.
    assert other.add(None, [5, 5, 5], [9, 9, 9]) == acc.add(None, [5, 5, 5], [9, 9, 9])
    assert other.rejected == dict.fromkeys(REJECT_REASONS, 0)


def test_commit_rejects_records_of_another_dimension():
    acc = make(dimension=2)
    with pytest.raises(ValueError, match="expected 2"):
        acc.commit(Measurement("a", (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 0.0))
    with pytest.raises(ValueError, match="unknown fiducial id"):
        acc.commit(EnabledChange("a", False))


def test_clear_and_empty_set_shapes():
    acc = make()
    acc.add("a", [0, 0, 0], [1, 1, 1])
    acc.clear()
    fs = acc.fiducial_set()
    assert fs.ids == () and fs.working.shape == (0, 3) and acc.n_measurements == 0


@pytest.mark.parametrize("kwargs, match", [
    (dict(dimension=4), "dimension must be 2 or 3"),
    (dict(working_frame=""), "working_frame must be a non-empty string"),
    (dict(merge_radius=0.0), "merge_radius must be > 0"),
    (dict(outlier_distance=-1.0), "outlier_distance must be >= 0"),
    (dict(merge_radius=math.nan), "merge_radius"),
    (dict(max_stamp_age=-1.0), "max_stamp_age must be >= 0"),
])
def test_constructor_validation(kwargs, match):
    args = dict(dimension=3, working_frame="tracker", destination_frame="world",
                merge_radius=0.005, outlier_distance=0.0)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        FiducialAccumulator(**args)


def test_rejected_measurement_reason_is_checked():
    with pytest.raises(ValueError, match="reason must be one of"):
        RejectedMeasurement("bogus", "x")


def test_fiducial_set_is_ready_for_build_model():
    model = pytest.importorskip("rbc_registration.core.model")
    rng = np.random.default_rng(1)
    dest, work = grid(rng)
    acc = make(outlier_distance=0.0)
    for _ in range(2):
        for k in range(len(dest)):
            acc.add(f"H{k}", work[k] + rng.normal(0, 1e-5, 3), dest[k])
    fs = acc.fiducial_set()
    m = model.build_model(fs.working, fs.destination, model.ModelConfig(dimension=3),
                          ids=list(fs.ids), repeat_statistics=fs.repeat_stats)
    assert tuple(m.ids) == fs.ids
    assert m.sigma_source == "repeats"


_point = st.tuples(*[st.floats(-1.0, 1.0, allow_nan=False)] * 3)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.sampled_from([None, "", "a", "b", "auto-0001"]), _point, _point,
                          st.booleans()), max_size=40))
def test_restore_is_identical_for_any_stream(stream):
    """Whatever was accepted or rejected, replaying the accepted records rebuilds the state."""
    acc = FiducialAccumulator(3, "tracker", "world", merge_radius=0.3, outlier_distance=0.5)
    records = []
    for fid, w, d, toggle in stream:
        try:
            rec = acc.prepare(fid, w, d)
        except RejectedMeasurement as exc:
            assert exc.reason == "outlier"
            continue
        acc.commit(rec)
        records.append(rec)
        if toggle:
            change = acc.prepare_enabled(rec.fiducial_id, not acc.is_enabled(rec.fiducial_id))
            acc.commit(change)
            records.append(change)
    other = FiducialAccumulator(3, "tracker", "world", merge_radius=0.01, outlier_distance=0.0)
    assert other.restore(records) == []
    assert other.state_digest() == acc.state_digest()
    assert other.n_measurements == acc.n_measurements
    a, b = acc.fiducial_set(), other.fiducial_set()
    assert a.ids == b.ids and a.disabled_ids == b.disabled_ids


def test_running_statistics_match_the_repeats_and_stay_small():
    """The store keeps running statistics per fiducial; they equal those of all the repeats."""
    from rbc_registration.core.decision.noise import estimate_sigma, repeat_stats
    rng = np.random.default_rng(7)
    acc = make(outlier_distance=0.0)
    reps = {f"H{k}": rng.normal(0, 1e-4, (n, 3)) + k for k, n in enumerate((1, 2, 5, 400))}
    for fid, rows in reps.items():
        for row in rows:
            acc.add(fid, row, row + 10.0)
    fs = acc.fiducial_set()
    want = repeat_stats(list(reps.values()))
    np.testing.assert_array_equal(fs.repeat_stats.counts, want.counts)
    np.testing.assert_allclose(fs.repeat_stats.variances, want.variances, rtol=1e-9)
    np.testing.assert_allclose(fs.working, [r.mean(axis=0) for r in reps.values()], atol=1e-12)
    assert estimate_sigma(list(reps.values())) == pytest.approx(
        float(np.sqrt(np.nanmean(fs.repeat_stats.variances))), rel=1e-9)


def test_an_exact_copy_is_a_duplicate_not_a_repeat():
    acc = make()
    acc.add("a", [0, 0, 0], [1, 1, 1], stamp_s=5.0)
    with pytest.raises(RejectedMeasurement) as caught:
        acc.add("a", [0, 0, 0], [1, 1, 1], stamp_s=5.0)
    assert caught.value.reason == "duplicate"
    assert "fiducial 'a' at stamp 5.000000000 s: the same points" in str(caught.value)
    assert acc.rejected["duplicate"] == 1 and acc.n_measurements == 1
    # the same points at another stamp are a repeat; other ids never collide
    acc.add("a", [0, 0, 0], [1, 1, 1], stamp_s=6.0)
    acc.add("b", [0.1, 0, 0], [1.1, 1, 1], stamp_s=5.0)
    assert acc.n_measurements == 3 and acc.fiducial_set().repeat_stats.counts.tolist() == [2, 1]


def test_one_stamp_with_other_points_is_a_conflict():
    acc = make()
    acc.add("a", [0, 0, 0], [1, 1, 1], stamp_s=5.0)
    with pytest.raises(RejectedMeasurement) as caught:
        acc.add("a", [0.0001, 0, 0], [1, 1, 1], stamp_s=5.0)
    assert caught.value.reason == "conflict" and acc.n_measurements == 1
    assert "one stamp is one measurement" in str(caught.value)


def test_points_without_an_id_at_one_stamp_are_two_measurements_unless_identical():
    acc = make(outlier_distance=0.01)
    fid = acc.add(None, [0, 0, 0], [1, 1, 1], stamp_s=5.0)
    assert acc.add(None, [0.001, 0, 0], [1.001, 1, 1], stamp_s=5.0) == fid
    with pytest.raises(RejectedMeasurement, match="the same points") as caught:
        acc.add(None, [0.001, 0, 0], [1.001, 1, 1], stamp_s=5.0)
    assert caught.value.reason == "duplicate" and acc.n_measurements == 2


def test_unstamped_measurements_are_never_duplicates():
    acc = make()
    for _ in range(3):
        acc.add("a", [0, 0, 0], [1, 1, 1])
    assert acc.n_measurements == 3 and acc.rejected["duplicate"] == 0


def test_the_duplicate_window_is_bounded():
    from rbc_registration.core.measurements.accumulator import DUPLICATE_WINDOW

    acc = make()
    for k in range(DUPLICATE_WINDOW + 1):
        acc.add("a", [0, 0, 0], [1, 1, 1], stamp_s=float(k))
    assert all(len(v) <= DUPLICATE_WINDOW for v in acc._recent.values())
    # stamp 0.0 fell out of the window: not detected (documented); the newest still is
    acc.add("a", [0, 0, 0], [1, 1, 1], stamp_s=0.0)
    with pytest.raises(RejectedMeasurement, match="the same points"):
        acc.add("a", [0, 0, 0], [1, 1, 1], stamp_s=float(DUPLICATE_WINDOW))


def test_a_copy_after_a_restore_is_still_a_duplicate():
    acc = make()
    rec = acc.prepare("a", [0, 0, 0], [1, 1, 1], stamp_s=5.0)
    acc.commit(rec)
    restarted = make()
    restarted.restore([rec])
    with pytest.raises(RejectedMeasurement) as caught:
        restarted.add("a", [0, 0, 0], [1, 1, 1], stamp_s=5.0)
    assert caught.value.reason == "duplicate"


def test_evaluate_keeps_every_stamp():
    """A bag recorded twice brings each copy after all of its fiducial's repeats: offline, the
    window is unbounded (``duplicate_window=None``)."""
    acc = FiducialAccumulator(3, "tracker", "world", 0.005, 0.002, duplicate_window=None)
    n = 40
    for _ in range(2):
        for k in range(n):
            try:
                acc.add("a", [0, 0, 1e-5 * k], [1, 1, 1], stamp_s=float(k + 1))
            except RejectedMeasurement as e:
                assert e.reason == "duplicate"
    assert acc.n_measurements == n and acc.rejected["duplicate"] == n
    with pytest.raises(ValueError, match="duplicate_window must be a positive integer"):
        FiducialAccumulator(3, "tracker", "world", 0.005, duplicate_window=0)


def test_points_whose_float_hashes_collide_are_still_other_points():
    """hash(-1.0) == hash(-2.0): the rule compares the points, not their hashes."""
    acc = make(outlier_distance=0.0)
    acc.add("a", [-1.0, 0, 0], [1, 1, 1], stamp_s=5.0)
    with pytest.raises(RejectedMeasurement) as caught:
        acc.add("a", [-2.0, 0, 0], [1, 1, 1], stamp_s=5.0)
    assert caught.value.reason == "conflict"


def test_an_id_that_was_not_utf8_is_malformed_live_but_kept_on_replay():
    """rclpy decodes a non-UTF-8 id to U+FFFD characters, so two holes sent as
    different invalid bytes became one fiducial (averaged, or one rejected as an outlier)."""
    from rbc_registration.core.measurements.accumulator import Measurement
    from rbc_registration.core.measurements.records import RejectedMeasurement

    acc = FiducialAccumulator(3, "tracker", "world", 0.005, 0.0)
    with pytest.raises(RejectedMeasurement, match="fiducial_id is not valid UTF-8") as info:
        acc.prepare("\ufffd\ufffdH", (0, 0, 0), (1, 1, 1), "tracker", "world", 1.0)
    assert info.value.reason == "malformed" and acc.rejected["malformed"] == 1
    # a journal written before the rule keeps its records
    acc.check_record(Measurement("\ufffd", (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 1.0, False))


def test_a_stamp_whose_nanosec_is_not_below_a_second_is_malformed():
    """(100 s, 4e9 ns) was read as 104 s and paired or conflicted with other
    measurements."""
    from rbc_registration.core.measurements.checks import stamp_seconds
    from rbc_registration.core.measurements.records import RejectedMeasurement

    assert stamp_seconds(100, 999_999_999) == pytest.approx(100.999999999)
    for nanosec in (1_000_000_000, 4_000_000_000):
        with pytest.raises(RejectedMeasurement, match="nanosec must be below 10") as info:
            stamp_seconds(100, nanosec)
        assert info.value.reason == "malformed"
