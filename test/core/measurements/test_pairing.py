"""Tests of the pure stamp pairer (no rclpy)."""

import math

import pytest

from rbc_registration.core.measurements.pairing import StampPairer


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


def test_two_candidates_within_the_slop_are_ambiguous_not_nearest_in_time():
    """Nearest in time won: with two destination points within the slop, the working point was
    paired with the nearer one silently, the wrong one under a clock offset (11 of 39
    measurements mispaired). The point is refused as ambiguous, with the hint."""
    p = StampPairer(slop=0.05)
    p.add_destination([1, 0, 0], "world", 1.00)
    p.add_destination([2, 0, 0], "world", 1.03)
    res = p.add_working([0, 0, 0], "tracker", 1.04)
    assert res.pairs == () and [d.stream for d in res.dropped] == [
        "working", "destination", "destination"]      # both candidates with it
    assert res.dropped[0].ambiguous and "ambiguous: 2 destination points within 0.05 s" in \
        res.dropped[0].reason and "lower pair_slop below half the measurement period" in \
        res.dropped[0].reason
    assert p.n_ambiguous == 3 and p.n_pairs == 0


@pytest.mark.parametrize("order", ["copies-after-each", "copies-after-both", "copies-late"])
def test_a_copied_point_is_a_duplicate_not_a_second_candidate(order):
    """both point topics recorded twice (two recorders) made every destination point
    one with two working points within the slop: every measurement refused as ambiguous. A
    copy (coordinates, frame and stamp) is dropped as a duplicate and pairing goes on."""
    w = [([k, 0, 0], "tracker", 1.0 + k) for k in range(4)]
    d = [([k, 1, 0], "world", 1.001 + k) for k in range(4)]
    if order == "copies-after-each":
        events = [e for k in range(4) for e in (("w", w[k]), ("w", w[k]), ("d", d[k]),
                                                  ("d", d[k]))]
    elif order == "copies-after-both":
        events = [e for k in range(4) for e in (("w", w[k]), ("d", d[k]), ("w", w[k]),
                                                  ("d", d[k]))]
    else:       # each copy after the next measurement's point (two recorders, one behind)
        events = [("w", w[0]), ("d", d[0])] + [
            e for k in range(1, 4) for e in (("w", w[k]), ("w", w[k - 1]), ("d", d[k]),
                                              ("d", d[k - 1]))] + [("w", w[3]), ("d", d[3])]
    p = StampPairer(slop=0.05)
    pairs, dropped = [], []
    for stream, args in events:
        res = (p.add_working if stream == "w" else p.add_destination)(*args)
        pairs += res.pairs
        dropped += res.dropped
    assert [(q.working.xyz[0], q.destination.xyz[0]) for q in pairs] == [(k, k) for k in range(4)]
    assert len(dropped) == 8 and all(x.duplicate and not x.ambiguous for x in dropped)
    assert "duplicate: the same working point and stamp 1.000000000 as one before" in \
        dropped[0].reason
    assert p.n_ambiguous == 0


def test_a_point_at_a_stamp_seen_before_elsewhere_is_no_duplicate():
    """Only an exact copy is a duplicate: the same stamp with other coordinates is not."""
    p = StampPairer(slop=0.05)
    p.add_working([0, 0, 0], "tracker", 1.0)
    res = p.add_working([0, 0, 1e-9], "tracker", 1.0)
    assert not any(x.duplicate for x in res.dropped) and res.repeated


def test_both_clocks_stepping_back_keep_the_first_pair():
    """both drivers restarted with new clocks (stamps back from 100 s to 5 s): the
    first working point was dropped at once, its destination partner then refused as ambiguous,
    and the first pair lost. It is buffered now and pairs; if only one driver restarted, the
    other stream's next point drops it as stale."""
    p = StampPairer(slop=0.02)
    for t in (100.0, 101.0, 102.0):
        p.add_working([t, 0, 0], "tracker", t)
        assert len(p.add_destination([t, 1, 0], "world", t + 0.001).pairs) == 1
    for t in (5.0, 6.0, 7.0):
        first = p.add_working([t, 0, 0], "tracker", t)
        second = p.add_destination([t, 1, 0], "world", t + 0.001)
        assert first.dropped == second.dropped == () and len(second.pairs) == 1, t
        assert second.pairs[0].working.xyz == (t, 0, 0)
    one = StampPairer(slop=0.02)
    one.add_working([100, 0, 0], "tracker", 100.0)
    one.add_destination([100, 1, 0], "world", 100.001)
    assert one.add_working([5, 0, 0], "tracker", 5.0).dropped == ()
    later = one.add_destination([101, 1, 0], "world", 101.001)
    assert [d.reason for d in later.dropped] == [
        "no destination point within 0.02 s of stamp 5.000000000"]


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
    # (only the first within the slop of the destination point: two would be ambiguous)
    assert p.add_destination([1, 0, 0], "w", 10.025).pairs[0].working.xyz == (1, 0, 0)


def test_a_late_point_does_not_cost_the_pairs_after_it():
    """A point late by more than the slop but less than RESTART_AFTER is an ordinary late
    point: the newer points buffered stay (D1.0, W2.0, W1.0, D2.0 lost W2-D2)."""
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
    arrival order then, and one lost message pairs every later point wrongly (FRE
    0.13 m, corrections applied). The pairer flags it for the warning."""
    p = StampPairer(slop=0.02)
    assert not p.add_working([0, 0, 0], "t", 0.0).repeated
    assert p.add_working([1, 0, 0], "t", 0.0).repeated
    assert not p.add_destination([0, 0, 0], "w", 0.0).repeated     # per stream
    assert not p.add_working([2, 0, 0], "t", 1.0).repeated


def test_a_candidate_already_paired_makes_the_later_point_ambiguous():
    """W 0.000 pairs with D 0.012 at once; W 0.020 is within the slop of D 0.012 too: it is
    refused as ambiguous (its only candidate is taken), not kept to pair with the next one."""
    p = StampPairer(slop=0.02)
    p.add_working([0, 0, 0], "t", 0.000)
    assert len(p.add_destination([0, 0, 0], "w", 0.012).pairs) == 1
    res = p.add_working([1, 0, 0], "t", 0.020)
    assert res.pairs == () and res.dropped[0].ambiguous
    assert "destination point at 0.012000000" in res.dropped[0].reason
    assert "paired or refused before" in res.dropped[0].reason
    assert p.pending("working") == 0


def test_the_candidates_of_an_ambiguous_point_are_refused_with_it():
    """W 0.000 has two destination points within the slop: it and both are refused (each has a
    contested point as its candidate), not dropped later as unpaired (malformed)."""
    p = StampPairer(slop=0.02)
    p.add_destination([0, 0, 0], "w", -0.012)
    p.add_destination([1, 0, 0], "w", 0.010)
    res = p.add_working([0, 0, 0], "t", 0.000)
    assert sorted((d.stream, d.point.stamp_s) for d in res.dropped if d.ambiguous) == [
        ("destination", -0.012), ("destination", 0.010), ("working", 0.0)]
    assert p.pending("destination") == 0 and p.n_ambiguous == 3


def test_a_point_near_two_buffered_points_is_refused_with_them():
    p = StampPairer(slop=0.02)
    p.add_working([0, 0, 0], "t", -0.005)
    p.add_working([0, 0, 0], "t", 0.000)      # two working points within the slop of D 0.010
    res = p.add_destination([1, 0, 0], "w", 0.010)
    assert res.pairs == () and len([d for d in res.dropped if d.ambiguous]) == 3
    assert p.pending("working") == 0


def stream_events(period, offset, delay_destination, n=39):
    """Working point k at 100 + k period, destination point k at that + offset; the destination
    point delivered ``delay_destination`` periods late (arrival order)."""
    events = []
    for k in range(n + delay_destination):
        if k < n:
            events.append(("working", 100.0 + k * period, k))
        j = k - delay_destination
        if 0 <= j < n:
            events.append(("destination", 100.0 + j * period + offset, j))
    return events


def feed(pairer, events):
    pairs, dropped = [], []
    for stream, stamp, k in events:
        res = pairer.add(stream, [k, 0, 0], "f", stamp)
        pairs += res.pairs
        dropped += res.dropped
    return pairs, dropped


@pytest.mark.parametrize("offset, delay", [(0.012, 0), (0.012, 1), (-0.008, 1), (0.004, 2)])
def test_a_period_within_the_slop_pairs_nothing_wrongly(offset, delay):
    """Streams 20 ms apart with the default 20 ms slop after a clock step between the devices:
    the nearest-in-time rule mispaired up to 38 of 39 silently. Now at most the first pair (made
    before a second candidate existed) is kept; every later point is refused and counted."""
    pairer = StampPairer(slop=0.02)
    pairs, dropped = feed(pairer, stream_events(0.02, offset, delay))
    assert len(pairs) <= 1 and all(pr.working.xyz == pr.destination.xyz for pr in pairs)
    assert pairer.n_ambiguous >= 39 * 2 - 4
    assert all("lower pair_slop below half the measurement period" in d.reason
               for d in dropped if d.ambiguous)


@pytest.mark.parametrize("offset, delay", [(0.0, 0), (0.019, 0), (-0.019, 1), (0.01, 2)])
def test_a_slop_below_half_the_period_is_never_ambiguous(offset, delay):
    """Period 50 ms, slop 20 ms (< 25 ms): any offset within the slop, any delivery delay:
    every point pairs with its own partner, nothing is ambiguous."""
    pairer = StampPairer(slop=0.02)
    pairs, dropped = feed(pairer, stream_events(0.05, offset, delay))
    assert len(pairs) == 39 and dropped == [] and pairer.n_ambiguous == 0
    assert all(pr.working.xyz == pr.destination.xyz for pr in pairs)


def test_a_discarded_point_is_no_candidate_of_the_ambiguity_rule():
    """~/take_sample records a buffered working point and discards it: its destination stamp
    partner is buffered as before, not refused as ambiguous ('paired or refused before')."""
    p = StampPairer(slop=0.02)
    p.add_working([1.0, 2.0, 3.0], "tracker", 5.0)
    assert p.discard("working", [1.0, 2.0, 3.0], 5.0)
    r = p.add_destination([4.0, 5.0, 6.0], "world", 5.0)
    assert r.pairs == () and r.dropped == () and p.pending("destination") == 1
    assert p.n_ambiguous == 0


def test_a_nan_point_does_not_turn_the_copy_rule_off():
    """A third review: NaN != NaN, so the copy of a NaN point (a tracker that lost its beam, in a
    topic recorded twice) looked like another point with the same stamp, the rule for streams
    whose stamps repeat turned copy dropping off, and every later copy made its measurement
    ambiguous (a bag lost all but 3 fiducials). A point with a NaN is no copy and tells
    nothing about the stamps; the later copies are dropped and every later pair is made."""
    p = StampPairer(slop=0.05)
    pairs, dropped = [], []
    for k in range(6):
        w = [math.nan, 0, 0] if k == 2 else [k, 0, 0]
        for stream, xyz, frame in (("w", w, "tracker"), ("w", w, "tracker"),
                                   ("d", [k, 1, 0], "world"), ("d", [k, 1, 0], "world")):
            res = (p.add_working if stream == "w" else p.add_destination)(xyz, frame, 1.0 + k)
            pairs += res.pairs
            dropped += res.dropped
    made = [q.working.xyz[0] for q in pairs]
    assert [x for x in made if not math.isnan(x)] == [0, 1, 3, 4, 5]
    # the copies of the 5 finite measurements and of the NaN one's destination point
    assert sum(x.duplicate for x in dropped) == 11
    assert not any(x.ambiguous and x.point.stamp_s > 3.5 for x in dropped)


def test_a_stream_whose_stamps_repeat_keeps_its_repeats():
    """Two different points in a row with one stamp (one stamp per session, or per hole): the
    stamps do not tell measurements apart, so an identical point after that is a repeat."""
    p = StampPairer(slop=0.05)
    for k in range(3):                      # one hole three times, working first, one stamp
        p.add_working([0.001 * k, 0, 0], "tracker", 7.0)
        res = p.add_destination([5, 5, 0], "world", 7.0)
        assert len(res.pairs) == 1 and not any(x.duplicate for x in res.dropped)
