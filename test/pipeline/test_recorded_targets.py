"""Targets recorded in a bag: repeats of an id averaged, refused when they do not agree (the
node's ``outlier_distance``, either frame)."""

import numpy as np
import pytest

from rbc_registration.pipeline.inputs import PairMessage
from rbc_registration.pipeline.offline import EvaluationError, recorded_targets
from rbc_registration.pipeline.settings import Settings

SETTINGS = Settings.from_mapping({"outlier_distance": 0.01})


def pair(tid, working, destination, k=0):
    return PairMessage(k, float(k), tid, tuple(working), SETTINGS.working_frame,
                       tuple(destination), SETTINGS.destination_frame)


def test_agreeing_repeats_are_averaged():
    t = recorded_targets([pair("a", (0, 0, 0), (1, 0, 0)), pair("b", (1, 0, 0), (2, 0, 0)),
                          pair("a", (0.002, 0, 0), (1, 0, 0))], SETTINGS)
    assert t.ids == ("a", "b")
    np.testing.assert_allclose(t.working[0], [0.001, 0, 0])


@pytest.mark.parametrize("second, frame", [(((0.5, 0, 0), (1, 0, 0)), "working"),
                                           (((0, 0, 0), (1.02, 0, 0)), "destination")])
def test_repeats_farther_than_outlier_distance_are_refused(second, frame):
    with pytest.raises(EvaluationError, match=rf"^cell\.mcap: target 'a' \(target message 3 of "
                                              rf"3\): conflicts .*target 'a': "
                                              rf"{frame} point is 0\.\d+ .*more than "
                                              r"outlier_distance 0\.01"):
        recorded_targets([pair("a", (0, 0, 0), (1, 0, 0)), pair("b", (1, 0, 0), (2, 0, 0)),
                          pair("a", *second)], SETTINGS, "cell.mcap")


def test_a_non_finite_target_is_named_with_the_bag_and_its_message():
    with pytest.raises(EvaluationError, match=r"^cell\.mcap: target 'b' \(target message 2 of 3\): "
                                              r"working point has NaN or inf \(2 such"):
        recorded_targets([pair("a", (0, 0, 0), (1, 0, 0)), pair("b", (np.nan, 0, 0), (2, 0, 0)),
                          pair("c", (0, np.inf, 0), (2, 0, 0))], SETTINGS, "cell.mcap")


def test_a_target_in_another_frame_is_named_with_the_bag_and_its_message():
    other = PairMessage(1, 1.0, "", (1, 0, 0), "camera", (2, 0, 0), SETTINGS.destination_frame)
    with pytest.raises(EvaluationError, match=r"^cell\.mcap: target 'target-1' \(target message 2 "
                                              r"of 2\): working frame 'camera', expected "):
        recorded_targets([pair("a", (0, 0, 0), (1, 0, 0)), other], SETTINGS, "cell.mcap")
