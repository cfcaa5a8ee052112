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
    with pytest.raises(EvaluationError, match=rf"target message 3 of 3 conflicts .*target 'a': "
                                              rf"{frame} point is 0\.\d+ .*more than "
                                              r"outlier_distance 0\.01"):
        recorded_targets([pair("a", (0, 0, 0), (1, 0, 0)), pair("b", (1, 0, 0), (2, 0, 0)),
                          pair("a", *second)], SETTINGS)
