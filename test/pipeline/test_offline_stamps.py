"""A bag's message whose stamp is not a time is rejected offline as the node rejects it."""

from rbc_registration.core.measurements.checks import stamp_seconds
from rbc_registration.core.measurements.records import RejectedMeasurement
from rbc_registration.pipeline.inputs import PairMessage, PointMessage
from rbc_registration.pipeline.offline import accumulate, settings_for


def _reason(sec, nanosec):
    try:
        stamp_seconds(sec, nanosec)
    except RejectedMeasurement as exc:
        return exc.message
    return ""


def test_messages_with_an_invalid_stamp_are_counted_malformed_and_not_used():
    good = PairMessage(0, 1.0, "H01", (0.0, 0.0, 0.0), "tracker", (1.0, 0.0, 0.0), "world")
    bad = PairMessage(1, float("nan"), "H02", (1.0, 0.0, 0.0), "tracker", (2.0, 0.0, 0.0),
                      "world", None, _reason(100, 4_000_000_000))
    point = PointMessage(2, "working", (0.0, 1.0, 0.0), "tracker", float("nan"),
                         _reason(5, 2_000_000_000))
    out = accumulate([good, bad, point], settings_for(3, {}))
    assert out.rejected["malformed"] == 2
    assert out.fiducials.ids == ("H01",)
    assert "FiducialPair 'H02': header.stamp.nanosec must be below 10^9" in \
        out.first_rejections["malformed"]
