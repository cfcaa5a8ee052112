"""Ambiguous point pairs through the node's ingestion (pure: no rclpy): counted under their own
reason, never a measurement; unambiguous streams ingested bit for bit as before."""

import numpy as np
import pytest

from rbc_registration.core.measurements.accumulator import FiducialAccumulator
from rbc_registration.core.measurements.pairing import StampPairer
from rbc_registration.core.synthetic.cells import make_cell
from rbc_registration.io.bag.records import SYNTH_PERIOD_S
from rbc_registration.io.bag.synthetic import cell_messages
from rbc_registration.pipeline.ingest import Ingest
from rbc_registration.pipeline.settings import SPECS


class Log:
    def __init__(self):
        self.lines = []

    def warning(self, text):
        self.lines.append(text)

    error = info = warning


class NearestInTime(StampPairer):
    """The pairer without the ambiguity rule: the nearest buffered point within the slop wins
    (the rule before it)."""

    def _ambiguous(self, stream, point, dropped):
        return False


def ingest_points(messages, pairer):
    acc = FiducialAccumulator(3, "tracker", "world", 0.005, 0.0)
    log = Log()
    ingest = Ingest(acc, pairer, None, log)
    for m in messages:
        stream = "working" if m.topic.endswith("working_point") else "destination"
        ingest.point(stream, m.xyz, m.frame_id, m.stamp_ns / 1e9)
    return ingest, acc, log


def test_the_synthetic_default_period_is_over_twice_the_default_slop():
    assert SYNTH_PERIOD_S > 2 * SPECS["pair_slop"].default


@pytest.mark.parametrize("cell, seed", [("A", 3), ("RA", 0)])
def test_unambiguous_streams_are_ingested_bit_for_bit_as_before(cell, seed):
    """A synthetic --points stream at the default period: the same fiducials, bit for bit, as
    the nearest-in-time rule gives, and nothing refused."""
    messages = [m for m in cell_messages(make_cell(cell, seed=seed), points=True)
                if m.topic.endswith("_point")]
    new, acc, _ = ingest_points(messages, StampPairer(0.02))
    old, _, _ = ingest_points(messages, NearestInTime(0.02))
    a, b = new.fiducial_set(), old.fiducial_set()
    assert a.ids == b.ids and a.n_measurements == b.n_measurements > 0
    assert np.array_equal(a.working, b.working) and np.array_equal(a.destination, b.destination)
    for x, y in zip(a.repeat_stats, b.repeat_stats):
        assert np.array_equal(x, y, equal_nan=True)
    assert sum(acc.rejected.values()) == 0


def test_ambiguous_points_are_counted_as_ambiguous_and_never_measured():
    """Period 20 ms = the slop, destination clock stepped by 12 ms: the nearest-in-time rule
    made a measurement of nearly every point; now at most the first pair (made before its second
    candidate existed) is one, the rest are rejected as ambiguous, logged with the hint."""
    cell = make_cell("RA", seed=0)
    messages = [m._replace(stamp_ns=m.stamp_ns + (12_000_000 if "destination" in m.topic else 0))
                for m in cell_messages(cell, period_s=0.02, points=True)
                if m.topic.endswith("_point")]
    ingest, acc, log = ingest_points(messages, StampPairer(0.02))
    _, old_acc, _ = ingest_points(messages, NearestInTime(0.02))
    assert old_acc.n_measurements > 0.9 * len(messages) / 2          # what it was
    assert acc.n_measurements <= 1
    assert acc.rejected["ambiguous"] >= len(messages) - 4 and acc.rejected["malformed"] == 0
    assert any("rejected measurement (ambiguous" in line and "lower pair_slop below half the "
               "measurement period" in line for line in log.lines)


def test_a_pair_made_again_is_a_duplicate_and_reported_as_recorded():
    """Both point streams bridged twice, copies in order W D W' D': the copies are
    duplicates (each point, dropped by the pairer before pairing: a copy would make the
    points of a bag recorded twice ambiguous), nothing is recorded twice, and the pair is
    reported as recorded once (``~/take_sample`` keeps the latest point's recorded mark for its
    copy, :class:`~rbc_registration.ros.samples.SampleTaker`)."""
    acc = FiducialAccumulator(3, "tracker", "world", 0.005, 0.0)
    ingest = Ingest(acc, StampPairer(0.02, 100), None, Log())
    w, d = (0.1, 0.2, 0.3), (1.1, 1.2, 1.3)
    recorded = []
    assert not ingest.point("working", w, "tracker", 5.0, recorded=recorded)
    assert len(ingest.point("destination", d, "world", 5.0, recorded=recorded)) == 1
    assert len(recorded) == 1
    assert not ingest.point("working", w, "tracker", 5.0, recorded=recorded)
    assert ingest.point("destination", d, "world", 5.0, recorded=recorded) == []
    assert len(recorded) == 1
    assert acc.rejected["duplicate"] == 2 and acc.n_measurements == 1


@pytest.mark.parametrize("stamp_ns", [0, 1_700_000_000_000_000_000])
@pytest.mark.parametrize("grouped", [False, True])
def test_unstamped_points_of_repeats_are_measurements_not_copies(grouped, stamp_ns):
    """drivers that leave header.stamp at 0 pair by arrival order,
    and a robot's destination point of a repeat of the same hole is the same, bit for bit. Every
    repeat's destination point was dropped as a 'duplicate' (250 of 375 in cell A with 3
    repeats), and with each hole measured 3 times back to back the waiting working point took the
    next hole's destination point (FRE 1.6 m). Unstamped points are never copies, as unstamped
    measurements are never duplicates: every repeat is a measurement of its own hole. A second
    review: the same with one constant stamp for every point (a driver stamping a session's
    time); once two different points share a stamp, no point is a copy."""
    cell = make_cell("A", seed=0, repeats=3)
    messages = [m._replace(stamp_ns=stamp_ns) for m in cell_messages(cell, points=True)
                if m.topic.endswith("_point")]
    if grouped:         # each hole 3 times, then the next (pairs of working, destination)
        pairs = [messages[i:i + 2] for i in range(0, len(messages), 2)]
        order = {}
        for p in pairs:
            order.setdefault(p[1].xyz, len(order))
        messages = [m for p in sorted(pairs, key=lambda p: order[p[1].xyz]) for m in p]
    ingest, acc, _ = ingest_points(messages, StampPairer(0.02))
    fs = ingest.fiducial_set()
    assert fs.n_measurements == len(messages) // 2 == 375 and acc.n_rejected == 0
    assert len(fs.ids) == 125 and set(fs.repeat_stats.counts) == {3}
    # every fiducial's working mean is the mean of its own hole's measurements
    truth = np.asarray(cell.fiducial_truth) / 1000.0
    near = np.linalg.norm(fs.destination[:, None, :] - truth[None], axis=2).argmin(axis=1)
    means = np.array([m.mean(axis=0) for m in cell.fiducial_measurements]) / 1000.0
    assert np.allclose(fs.working, means[near], rtol=0, atol=1e-12)
