"""The sessions in the model state (pipeline/state.py): the warning line of a moved session and
of a session the node opened itself, and a new session that shares too few fiducials with the
earlier ones: no model, and the error says why and what to measure."""

import numpy as np

from rbc_registration.core.measurements.accumulator import FiducialAccumulator
from rbc_registration.pipeline.offline import settings_for
from rbc_registration.pipeline.state import build_state

SETTINGS = settings_for(3, {})


def _grid(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.array([[x, y, z] for x in (0, .4, .8) for y in (0, .4, .8) for z in (0, .3)],
                    dtype=float) + rng.normal(0, 0.01, (18, 3))


def _acc() -> FiducialAccumulator:
    return FiducialAccumulator(3, "tracker", "world", 0.005, 0.01)


def test_a_new_session_with_too_few_common_fiducials_says_what_to_measure():
    pts = _grid(0)
    rng = np.random.default_rng(1)
    acc = _acc()
    for k, p in enumerate(pts):
        acc.add(f"F{k}", p + rng.normal(0, 2e-5, 3), p, stamp_s=1.0 + k)
    shift = np.array([1e-3, -5e-4, 2e-4])     # the tracker moved by ~1.1 mm; noise 20 um
    acc.add("F0", pts[0] + shift + rng.normal(0, 2e-5, 3), pts[0], stamp_s=50.0,
            session="after lunch")
    state = build_state(acc.fiducial_set(), SETTINGS, 0)
    assert state.model is None
    assert state.error.startswith("1 enabled fiducials, need min_fiducials=4 in session "
                                  "'after lunch'; session '1' shares 1 fiducial(s)")
    assert ("kept apart, 18 measurement(s) left out: measure at least 4 fiducials of the "
            "earlier sessions again (not on one line) in session 'after lunch'") in state.error
    for k in (1, 7, 12, 17):    # four more, spread: the first session joins, re-stationed
        acc.add(f"F{k}", pts[k] + shift + rng.normal(0, 2e-5, 3), pts[k], stamp_s=50.0 + k)
    state = build_state(acc.fiducial_set(), SETTINGS, 0)
    assert state.error == "" and len(state.fiducials.ids) == 18
    assert "session '1' moved against 'after lunch'" in state.warning
    assert "re-stationed (sessions start at stamp '1' at 1.000 s, 'after lunch' at 50.000 s)" \
        in state.warning
    assert "the node detected" not in state.warning


def test_a_session_the_node_opened_is_named_with_its_first_stamp():
    pts = _grid(2)
    rng = np.random.default_rng(3)
    acc = _acc()
    for k, p in enumerate(pts):
        acc.add(f"F{k}", p + rng.normal(0, 2e-5, 3), p, stamp_s=1.0 + k)
    angle = 2e-3
    rot = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0],
                    [0, 0, 1]])
    for k, p in enumerate(pts):   # a bump nobody declared: 1 mm and 2 mrad, noise 20 um
        acc.add(f"F{k}", p @ rot.T + [1e-3, 0, 0] + rng.normal(0, 2e-5, 3), p,
                stamp_s=100.0 + k)
    assert acc.sessions.names == ("1", "auto-1")
    start = dict(acc.fiducial_set().session_starts)["auto-1"]
    state = build_state(acc.fiducial_set(), SETTINGS, 0)
    assert state.model is not None
    assert "session '1' moved against 'auto-1'" in state.warning
    assert (f"the node detected a move of the working frame and opened session(s) 'auto-1' at "
            f"stamp {start:.3f} s") in state.warning
    assert start == 100.0
