"""A calibration's ``answers`` (docs/CALIBRATION.md): written by ``~/save``'s
``calibration_from_state``, read back bit for bit, and the model built from them answers targets
exactly as the live model did (every field of ``correct``: corrected, uncorrected, destination,
expected TRE and bound), for each interpolation, decision and dimension. A file whose answers
do not belong to it is refused in one line naming the field."""

import dataclasses

import numpy as np
import pytest
import yaml

from rbc_registration.core.measurements.accumulator import FiducialAccumulator
from rbc_registration.io.calibration import read_calibration, write_calibration
from rbc_registration.io.calibration_model import calibration_from_state
from rbc_registration.pipeline.settings import Settings
from rbc_registration.pipeline.state import build_state


def _state(dimension, interpolation, decision, seed=0, repeats=2):
    """A served model state as the node builds it (metres): a bent 3 x 3 x 2 (3D) or 4 x 4
    (2D) grid of fiducials measured ``repeats`` times."""
    rng = np.random.default_rng(seed)
    settings = Settings.from_mapping({"working_frame": "laser", "destination_frame": "base",
                                      "dimension": dimension, "interpolation": interpolation,
                                      "decision": decision, "state_dir": ""})
    acc = FiducialAccumulator(dimension, "laser", "base", 0.005, 0.0)
    if dimension == 3:
        truth = np.array([[x, y, z] for x in range(3) for y in range(3) for z in range(2)]) * 0.4
    else:
        truth = np.array([[x, y, 0.0] for x in range(4) for y in range(4)]) * 0.3
    for _repeat in range(repeats):
        for k, p in enumerate(truth):
            working = p[[1, 0, 2]] * [1, -1, 1] + 0.5 + 1e-3 * np.sin(3 * p) \
                + rng.normal(0, 3e-5, 3)
            if dimension == 2:
                working[2] = 0.0
            acc.add(f"F{k}", working, p)
    state = build_state(acc.fiducial_set(), settings, 1_700_000_000_500_000_000)
    assert state.model is not None, state.error
    return state, settings


def _targets(working, n=40, seed=1):
    """Targets inside the fiducials' hull and outside it (working frame, metres): uniform over
    their bounding box grown by 30 % on each side."""
    rng = np.random.default_rng(seed)
    lo, hi = working.min(axis=0), working.max(axis=0)
    return lo + (hi - lo) * rng.uniform(-0.3, 1.3, (n, working.shape[1]))


CASES = [(3, "paper", "on"), (3, "kriging", "on"), (3, "paper", "cv"), (3, "kriging", "cv"),
         (3, "paper", "off"), (2, "paper", "on"), (2, "kriging", "cv")]


@pytest.mark.parametrize("dimension, interpolation, decision", CASES)
def test_saved_answers_answer_as_the_live_model(tmp_path, dimension, interpolation, decision):
    state, settings = _state(dimension, interpolation, decision)
    live = state.model
    path = str(tmp_path / "cell.yaml")
    write_calibration(path, calibration_from_state(state, settings, "corrected"))
    cal = read_calibration(path)
    assert cal.answers is not None and cal.answers == calibration_from_state(
        state, settings, "corrected").answers          # a round trip, bit for bit
    saved = cal.answers.model(cal.sigma)
    assert saved.decision.method == live.decision.method == cal.decision.method
    targets = _targets(live.working)
    want, got = live.correct(targets), saved.correct(targets)
    assert want.inside_hull.any() and not want.inside_hull.all()
    for name in want._fields:
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)
    a, b = live.answer(targets), saved.answer(targets)
    for name in a._fields:
        np.testing.assert_array_equal(getattr(b, name), getattr(a, name), err_msg=name)


def test_an_uncorrected_file_holds_the_same_answers(tmp_path):
    """Saved with ``registration: uncorrected`` (tf_broadcast uncorrected) the answers are the
    model's too: targets get what the live model gives, whichever registration tf carries."""
    state, settings = _state(3, "kriging", "on")
    path = str(tmp_path / "cell.yaml")
    write_calibration(path, calibration_from_state(state, settings, "uncorrected"))
    cal = read_calibration(path)
    targets = _targets(state.model.working)
    np.testing.assert_array_equal(cal.answers.model(cal.sigma).correct(targets).destination,
                                  state.model.correct(targets).destination)


@pytest.fixture(scope="module")
def saved_doc(tmp_path_factory):
    state, settings = _state(3, "kriging", "cv")
    path = str(tmp_path_factory.mktemp("answers") / "cell.yaml")
    write_calibration(path, calibration_from_state(state, settings, "corrected"))
    with open(path, encoding="utf-8") as f:
        return yaml.safe_load(f)


def _set(doc, dotted, value):
    doc = yaml.safe_load(yaml.safe_dump(doc))      # a deep copy
    node = doc
    *path, last = dotted.split(".")
    for key in path:
        node = node[int(key)] if isinstance(node, list) else node[key]
    if isinstance(node, list):
        node[int(last)] = value
    else:
        node[last] = value
    return doc


@pytest.mark.parametrize("dotted, value, message", [
    ("n_fiducials", 17, "answers.fiducials: 18 fiducials, but n_fiducials is 17"),
    ("answers.corrected.translation", [0.1, 0.2, 0.3],
     "answers.corrected: differs from translation/rotation by"),
    ("answers.kriging", None, "answers.kriging: null, but the answers need kriging"),
    ("answers.interpolation", "nearest", "answers.interpolation: must be one of"),
    ("answers.fiducials.3.id", "F0", "answers.fiducials: the id 'F0' is given twice"),
    ("answers.fiducials.2.repeats", 0, "answers.fiducials[2].repeats: must be"),
    ("answers.fiducials.1.working", [1.0, 2.0], "answers.fiducials[1].working"),
    ("answers.error_model.level", 1.5, "answers.error_model.level: must be in (0, 1)"),
    ("answers.error_model.scaled", "yes", "answers.error_model.scaled: must be true or false"),
    ("answers.corrected.rotation", [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
     "answers.corrected.rotation: must have 3 rows"),
    ("answers.colour", "red", "answers.colour: unknown field"),
])
def test_answers_that_do_not_belong_are_refused_in_one_line(tmp_path, saved_doc, dotted, value,
                                                           message):
    path = tmp_path / "cal.yaml"
    path.write_text(yaml.safe_dump(_set(saved_doc, dotted, value), sort_keys=False))
    with pytest.raises(ValueError) as info:
        read_calibration(str(path))
    text = str(info.value)
    assert text.startswith(f"{path}: ") and message in text and "\n" not in text, text


def test_a_version_2_file_reads_without_answers(tmp_path, saved_doc):
    doc = {k: v for k, v in saved_doc.items() if k != "answers"}
    path = tmp_path / "v2.yaml"
    path.write_text(yaml.safe_dump({**doc, "format_version": 2}, sort_keys=False))
    cal = read_calibration(str(path))
    assert cal.answers is None
    path.write_text(yaml.safe_dump({**saved_doc, "format_version": 2}, sort_keys=False))
    with pytest.raises(ValueError, match="answers: unknown field"):
        read_calibration(str(path))
    assert dataclasses.replace(cal, answers=None) == cal
