"""``~/markers`` built from a model state (message types only, no rclpy.init): the disabled
fiducials labelled where they are (issue 10 item 6), the count bounded by ``max_markers``."""

import sys
import os

import numpy as np
import pytest

pytest.importorskip("rbc_registration_interfaces.msg")

from builtin_interfaces.msg import Time  # noqa: E402
from visualization_msgs.msg import Marker  # noqa: E402

from rbc_registration.core.measurements.accumulator import FiducialAccumulator  # noqa: E402
from rbc_registration.core.measurements.pairing import StampPairer  # noqa: E402
from rbc_registration.pipeline.ingest import Ingest  # noqa: E402
from rbc_registration.pipeline.settings import Settings  # noqa: E402
from rbc_registration.pipeline.state import EMPTY_STATE, build_state  # noqa: E402
from rbc_registration.ros.markers import largest, markers_msg  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ros_helpers import make_cell  # noqa: E402


class Log:
    def warning(self, *a): pass
    error = info = warning


def ingest_cell(dimension=3, disabled=("H3", "H17")):
    cell = make_cell(seed=0, repeats=2)
    acc = FiducialAccumulator(dimension, "tracker", "world", 0.005, 0.0)
    ingest = Ingest(acc, StampPairer(0.02, 100), None, Log())
    for k in range(len(cell["fid"])):
        assert ingest.measurement((f"H{cell['fid'][k]}", cell["working"][k],
                                   cell["destination"][k], "", "", 1.0 + k))
    for fid in disabled:
        assert ingest.set_enabled(fid, False)[0]
    return ingest, cell


def by_ns(msg, name):
    return [m for m in msg.markers if m.ns == f"rbc_registration/{name}"]


@pytest.mark.parametrize("dimension", [2, 3])
def test_disabled_fiducials_are_labelled_at_their_location(dimension):
    ingest, cell = ingest_cell(dimension)
    settings = Settings.from_mapping({"dimension": dimension})
    state = build_state(ingest.fiducial_set(), settings, 1)
    msg = markers_msg(state, settings, Time(sec=1), ingest.disabled_points())
    labels = by_ns(msg, "disabled")
    assert [m.text for m in labels] == ["disabled: H3", "disabled: H17"]
    for label, k in zip(labels, (3, 17)):
        truth = cell["destination"][cell["fid"] == k].mean(axis=0)
        want = [*truth[:dimension], *([0.0] if dimension == 2 else [])]
        want[2] += settings.marker_scale
        got = [label.pose.position.x, label.pose.position.y, label.pose.position.z]
        np.testing.assert_allclose(got, want, atol=1e-4)   # 50 um noise of 2 repeats
        assert np.linalg.norm(got) > 0.1                   # not the world origin
        assert label.type == Marker.TEXT_VIEW_FACING and label.header.frame_id == "world"
    grey = by_ns(msg, "disabled_fiducials")
    assert len(grey) == 1 and len(grey[0].points) == 2
    assert len(by_ns(msg, "fiducials")[0].points) == 46
    assert len(by_ns(msg, "corrections")) == 46
    assert state.model is not None


def test_max_markers_bounds_arrows_and_labels_keeping_the_largest_corrections():
    ingest, _ = ingest_cell()
    state = build_state(ingest.fiducial_set(), Settings.from_mapping({}), 1)
    full = markers_msg(state, Settings.from_mapping({}), Time(), ingest.disabled_points())
    lengths = {m.id: np.hypot.reduce([m.points[1].x - m.points[0].x,
                                      m.points[1].y - m.points[0].y,
                                      m.points[1].z - m.points[0].z])
               for m in by_ns(full, "corrections")}
    for max_markers in (0, 1, 12):
        settings = Settings.from_mapping({"max_markers": max_markers})
        msg = markers_msg(state, settings, Time(), ingest.disabled_points())
        labels, arrows = by_ns(msg, "disabled"), by_ns(msg, "corrections")
        assert len(labels) == min(2, max_markers)
        assert len(arrows) == max(0, max_markers - 2)
        kept = sorted(lengths, key=lambda i: -lengths[i])[:len(arrows)]
        assert sorted(m.id for m in arrows) == sorted(kept)
        assert len(by_ns(msg, "fiducials")[0].points) == 46   # every fiducial still drawn


def test_largest_and_empty_state():
    assert largest(np.array([1.0, 5.0, 3.0, 4.0]), 2).tolist() == [1, 3]
    assert largest(np.array([1.0, 2.0]), 5).tolist() == [0, 1]
    assert largest(np.array([1.0, 2.0]), 0).tolist() == []
    msg = markers_msg(EMPTY_STATE, Settings.from_mapping({}), Time())
    assert [m.action for m in msg.markers] == [Marker.DELETEALL]
