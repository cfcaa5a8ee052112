"""Tests of the pure stamp pairer (no rclpy)."""

import math

import pytest

from rbc_registration.core.pairing import StampPairer


def test_pairs_within_slop_either_order():
    p = StampPairer(slop=0.01)
    assert p.add_working([1, 2, 3], "tracker", 10.0).pairs == ()
    res = p.add_destination([4, 5, 6], "world", 10.005)
    assert len(res.pairs) == 1 and res.dropped == ()
    pair = res.pairs[0]
    assert pair.working.xyz == (1, 2, 3) and pair.destination.xyz == (4, 5, 6)
    assert pair.working.frame_id == "tracker" and pair.destination.frame_id == "world"
    assert pair.stamp_s == 10.0
    # destination first
    assert p.add_destination([0, 0, 0], "world", 11.0).pairs == ()
    assert len(p.add_working([0, 0, 0], "tracker", 10.995).pairs) == 1
    assert p.pending("working") == p.pending("destination") == 0 and p.n_pairs == 2


def test_nearest_in_time_wins():
    p = StampPairer(slop=0.05)
    p.add_destination([1, 0, 0], "world", 1.00)
    p.add_destination([2, 0, 0], "world", 1.03)
    res = p.add_working([0, 0, 0], "tracker", 1.04)
    assert res.pairs[0].destination.xyz == (2, 0, 0)


def test_stale_points_are_dropped_and_counted():
    p = StampPairer(slop=0.01)
    p.add_working([0, 0, 0], "tracker", 1.0)         # its destination never comes
    res = p.add_destination([1, 1, 1], "world", 2.0)
    assert res.pairs == ()
    assert [d.stream for d in res.dropped] == ["working"]
    assert "no destination point within 0.01 s" in res.dropped[0].reason
    # A working point whose window the destination stream has passed is dropped at once.
    res = p.add_working([0, 0, 0], "tracker", 1.5)
    assert res.pairs == () and [d.stream for d in res.dropped] == ["working"]
    assert p.n_dropped == 2
    # The buffered destination (2.0) still pairs with its working point.
    assert len(p.add_working([0, 0, 0], "tracker", 2.001).pairs) == 1


def test_buffers_are_bounded():
    p = StampPairer(slop=0.01, max_buffer=3)
    dropped = []
    for k in range(5):
        dropped += p.add_working([k, 0, 0], "tracker", float(k)).dropped
    assert p.pending("working") == 3
    assert [d.point.xyz[0] for d in dropped] == [0, 1]
    assert all("buffer full" in d.reason for d in dropped)


def test_nan_coordinates_pass_through_to_the_accumulator():
    p = StampPairer(slop=0.01)
    p.add_working([math.nan, 0, 0], "tracker", 1.0)
    res = p.add_destination([0, 0, 0], "world", 1.0)
    assert math.isnan(res.pairs[0].working.xyz[0])


@pytest.mark.parametrize("args, match", [
    (("working", [0, 0], "t", 1.0), "must have 3 coordinates"),
    (("working", [0, 0, 0], "t", math.inf), "stamp must be finite"),
    (("sideways", [0, 0, 0], "t", 1.0), "stream must be"),
])
def test_bad_points_raise(args, match):
    p = StampPairer(slop=0.01)
    with pytest.raises(ValueError, match=match):
        p.add(*args)
    assert p.pending("working") == 0


@pytest.mark.parametrize("slop", [0.0, -1.0, math.nan, math.inf])
def test_bad_slop(slop):
    with pytest.raises(ValueError, match="slop must be > 0"):
        StampPairer(slop=slop)


def test_bad_buffer_size():
    with pytest.raises(ValueError, match="max_buffer"):
        StampPairer(slop=0.1, max_buffer=0)


def test_clear():
    p = StampPairer(slop=0.01)
    p.add_working([0, 0, 0], "tracker", 5.0)
    p.clear()
    assert p.pending("working") == 0
    assert len(p.add_working([0, 0, 0], "tracker", 1.0).pairs) == 0  # no stale horizon left


@pytest.mark.parametrize("poisoned", ["working", "destination"])
def test_one_future_stamp_does_not_stop_the_pairing(poisoned):
    """A point stamped 2**31 s (or a driver restarted with another clock) was kept as the
    stream's latest stamp, so every later point of the other stream looked stale: 0 of 20 pairs
    until a reset. The stream now restarts from its next point; at most the pair in flight is
    lost, and the future point is dropped as out of order."""
    p = StampPairer(slop=0.02)
    p.add(poisoned, [9, 9, 9], "f", 2.0 ** 31)
    first, second = ("destination", "working") if poisoned == "working" else (
        "working", "destination")
    pairs, dropped = [], []
    for k in range(20):
        for stream in (first, second):
            res = p.add(stream, [k, 0, 0], "f", 100.0 + k)
            pairs += res.pairs
            dropped += res.dropped
    assert len(pairs) >= 19
    assert all(pr.working.xyz == pr.destination.xyz for pr in pairs)
    assert any(d.point.stamp_s == 2.0 ** 31 and "out of order" in d.reason for d in dropped)
    assert p.pending("working") == p.pending("destination") == 0


def test_points_slightly_out_of_order_within_the_slop_still_pair():
    p = StampPairer(slop=0.02)
    p.add_working([1, 0, 0], "t", 10.010)
    p.add_working([2, 0, 0], "t", 10.000)     # back by less than the slop: no restart
    assert p.pending("working") == 2
    assert p.add_destination([1, 0, 0], "w", 10.011).pairs[0].working.xyz == (1, 0, 0)


def test_a_late_point_does_not_cost_the_pairs_after_it():
    """A point late by more than the slop but less than RESTART_AFTER is an ordinary late
    point: the newer points buffered stay (a review: D1.0, W2.0, W1.0, D2.0 lost W2-D2)."""
    p = StampPairer(slop=0.05)
    pairs = []
    for stream, stamp in [("destination", 1.0), ("working", 2.0), ("working", 1.0),
                          ("destination", 2.0), ("working", 3.0), ("destination", 3.0)]:
        pairs += p.add(stream, [stamp, 0, 0], "f", stamp).pairs
    assert sorted(pr.stamp_s for pr in pairs) == [2.0, 3.0]    # D1.0 was stale when W1 came


def test_discard_drops_one_buffered_point():
    p = StampPairer(slop=0.05)
    p.add_working([1, 2, 3], "t", 5.0)
    assert not p.discard("working", [1, 2, 3], 5.1) and p.pending("working") == 1
    assert p.discard("working", [1, 2, 3], 5.0) and p.pending("working") == 0
    assert p.add_destination([0, 0, 0], "w", 5.0).pairs == ()


def test_repeated_stamps_are_flagged():
    """Stamps that do not tell measurements apart (a driver that stamps 0): pairing goes by
    arrival order then, and one lost message pairs every later point wrongly (a review: FRE
    0.13 m, corrections applied). The pairer flags it for the warning."""
    p = StampPairer(slop=0.02)
    assert not p.add_working([0, 0, 0], "t", 0.0).repeated
    assert p.add_working([1, 0, 0], "t", 0.0).repeated
    assert not p.add_destination([0, 0, 0], "w", 0.0).repeated     # per stream
    assert not p.add_working([2, 0, 0], "t", 1.0).repeated
