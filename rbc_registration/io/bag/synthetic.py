"""A synthetic cell (:func:`rbc_registration.core.synthetic.cells.make_cell`, millimetres) as the
messages of a recorded bag (metres), for ``synth-bag``, the demo and the tests."""

from __future__ import annotations

from typing import Any, Iterator, Sequence

import numpy as np

from ...core.constants import M_PER_MM
from .records import DEFAULT_TOPICS, SYNTH_PERIOD_S, OutMessage, Topics

SYNTH_START_NS = 1_700_000_000 * 1_000_000_000  # first stamp of a synthetic bag


def _passes(groups: Sequence[Sequence[Any]]) -> Iterator[tuple[int, Any]]:
    """(j, measurement) of every group, pass by pass: the first of each, then the second, ..."""
    for r in range(max(len(g) for g in groups)):
        for j, g in enumerate(groups):
            if r < len(g):
                yield j, g[r]


def _xyz(p: np.ndarray) -> tuple[float, float, float]:
    """A point in mm (2D or 3D) -> (x, y, z) in metres, z = 0 in 2D."""
    v = np.asarray(p, dtype=float) * M_PER_MM
    return (float(v[0]), float(v[1]), float(v[2]) if len(v) > 2 else 0.0)


def cell_messages(cell: Any, topics: Topics = DEFAULT_TOPICS, working_frame: str = "tracker",
                  destination_frame: str = "world", period_s: float = SYNTH_PERIOD_S,
                  points: bool = False, start_ns: int = SYNTH_START_NS) -> Iterator[OutMessage]:
    """The messages of a synthetic cell (mm) as recorded from a robot visiting the holes, in
    metres: every fiducial once, then the repeated ones again, pass by pass; then the targets
    (with truth) the same way. Stamps ``period_s`` apart; 2D cells get z = 0.

    :param points: fiducials as a working and a destination ``PointStamped`` with one stamp
        (ids then assigned by the node's proximity rule) instead of ``FiducialPair``.
    """
    step = int(round(period_s * 1e9))
    k = 0
    for j, w in _passes(cell.fiducial_measurements):
        stamp = start_ns + k * step
        d = _xyz(cell.fiducial_truth[j])
        if points:
            yield OutMessage(topics.working_point, "point", stamp, working_frame, _xyz(w))
            yield OutMessage(topics.destination_point, "point", stamp, destination_frame, d)
        else:
            yield OutMessage(topics.fiducial_pairs, "pair", stamp, working_frame, _xyz(w),
                             cell.fiducial_ids[j], destination_frame, d)
        k += 1
    for j, w in _passes(cell.target_measurements):
        yield OutMessage(topics.targets, "pair", start_ns + k * step, working_frame, _xyz(w),
                         cell.target_ids[j], destination_frame, _xyz(cell.target_truth[j]))
        k += 1


def cell_message_count(cell: Any, points: bool = False) -> tuple[int, int, int]:
    """(fiducial measurements, target measurements, messages) that :func:`cell_messages`
    yields for ``cell``."""
    n_fid = sum(len(m) for m in cell.fiducial_measurements)
    n_tgt = sum(len(m) for m in cell.target_measurements)
    return n_fid, n_tgt, n_fid * (2 if points else 1) + n_tgt
