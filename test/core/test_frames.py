"""The tf frame-id rule (core/frames.py), shared by the node's parameters and calibration files."""

import pytest

from rbc_registration.core.frames import MAX_FRAME_ID, frame_id_problem, same_frame_problem


@pytest.mark.parametrize("frame", ["world", "base_link", "cell_a/tracker", "a" * MAX_FRAME_ID])
def test_good_frame_ids(frame):
    assert frame_id_problem(frame) is None


@pytest.mark.parametrize("frame, problem", [
    ("", "must not be empty"), ("/world", "must not start with '/'"),
    ("my frame", "whitespace"), ("tab\tframe", "whitespace"), ("bell\x07", "control"),
    ("a" * (MAX_FRAME_ID + 1), f"at most {MAX_FRAME_ID} characters")])
def test_bad_frame_ids_say_why(frame, problem):
    assert problem in frame_id_problem(frame)


def test_a_registration_needs_two_frames():
    assert same_frame_problem("destination_frame", "world", "tracker") is None
    problem = same_frame_problem("destination_frame", "world", "world")
    assert problem.startswith("must differ from destination_frame, both are 'world'")
