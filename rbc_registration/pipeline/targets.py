"""Targets to correct and evaluate, and the one rule for repeated rows of an id: their mean,
in first-seen order (CSV targets, targets recorded in a bag), refused when a row lies farther
than a limit from the mean of its id's earlier rows (:func:`first_conflict`).
"""

from __future__ import annotations

from typing import NamedTuple, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..core.repeats import repeat_outlier


class Targets(NamedTuple):
    """Targets: ids, working-frame points (K, d), truth (K, d) or ``None``, and where they came
    from (a file name or ``"bag"``). Unit of the data (metres for bags)."""

    ids: tuple[str, ...]
    working: NDArray[np.float64]
    destination: Optional[NDArray[np.float64]]
    source: str


def with_truth(destination: Optional[ArrayLike], count: int) -> NDArray[np.bool_]:
    """Which of ``count`` targets have truth: a finite row of ``destination`` (K, d); a row
    with a NaN is a target without (a bag's target message with a NaN destination point);
    ``None``: none has."""
    if destination is None:
        return np.zeros(count, dtype=bool)
    return np.isfinite(np.asarray(destination, dtype=np.float64)).all(axis=1)


def rows_by_id(ids: Sequence[str]) -> dict[str, list[int]]:
    """The row indices of each id (one id per row), the ids in order of first appearance."""
    rows: dict[str, list[int]] = {}
    for k, key in enumerate(ids):
        rows.setdefault(key, []).append(k)
    return rows


def mean_by_id(ids: Sequence[str], *columns: ArrayLike) -> tuple[tuple[str, ...],
                                                                  list[NDArray[np.float64]]]:
    """Average the rows of each id, in order of first appearance.

    :param ids: one id per row.
    :param columns: arrays with one row per id, e.g. working points (N, d) and truth (N, d).
    :return: the distinct ids and, per column, the (J, ...) means.
    :raises ValueError: when a column has another number of rows than ``ids``.
    """
    rows = rows_by_id(ids)
    means = []
    for column in columns:
        values = np.asarray(column, dtype=np.float64)
        if len(values) != len(ids):
            raise ValueError(f"got {len(values)} rows for {len(ids)} ids")
        means.append(np.array([values[index].mean(axis=0) for index in rows.values()]))
    return tuple(rows), means


class Conflict(NamedTuple):
    """A repeated row of an id that lies too far from the id's earlier rows.

    :ivar row: its index among the rows; ``first``: the index of the id's first row.
    :ivar frame: the frame it conflicts in; ``message``: id, distance and limit in words.
    """

    row: int
    first: int
    frame: str
    message: str


def first_conflict(ids: Sequence[str], frames: Sequence[tuple[str, ArrayLike, float, str]],
                   kind: str = "target") -> Optional[Conflict]:
    """The first repeated row (frame by frame, in row order) farther than its frame's limit from
    the mean of its id's earlier rows (:func:`~rbc_registration.core.repeats.repeat_outlier`):
    two points under one id.

    :param ids: one id per row.
    :param frames: per frame ``(name, points (N, d), limit, how the limit is named)``; a limit
        of 0 switches that frame's check off.
    :param kind: what the ids are, for the message (``target``, ``candidate``).
    :return: :class:`Conflict`, or None when every id's rows agree.
    """
    rows = rows_by_id(ids)
    for name, points, limit, limit_name in frames:
        values = np.asarray(points, dtype=np.float64)
        for key, index in rows.items():
            if len(index) < 2:
                continue
            # the mean of the rows before each row, from running sums: linear in the repeats
            own = values[index]
            before = (np.cumsum(own, axis=0)[:-1] / np.arange(1, len(index))[:, None]).tolist()
            own_rows = own.tolist()
            for i in range(1, len(index)):
                far = repeat_outlier(key, name, own_rows[i], before[i - 1], i, limit,
                                     limit_name, kind)
                if far:
                    return Conflict(index[i], index[0], name, far)
    return None
