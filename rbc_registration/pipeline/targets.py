"""Targets to correct and evaluate, and the one rule for repeated rows of an id: their mean,
in first-seen order (CSV targets, targets recorded in a bag).
"""

from __future__ import annotations

from typing import NamedTuple, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray


class Targets(NamedTuple):
    """Targets: ids, working-frame points (K, d), truth (K, d) or ``None``, and where they came
    from (a file name or ``"bag"``). Unit of the data (metres for bags)."""

    ids: tuple[str, ...]
    working: NDArray[np.float64]
    destination: Optional[NDArray[np.float64]]
    source: str


def mean_by_id(ids: Sequence[str], *columns: ArrayLike) -> tuple[tuple[str, ...],
                                                                  list[NDArray[np.float64]]]:
    """Average the rows of each id, in order of first appearance.

    :param ids: one id per row.
    :param columns: arrays with one row per id, e.g. working points (N, d) and truth (N, d).
    :return: the distinct ids and, per column, the (J, ...) means.
    :raises ValueError: when a column has another number of rows than ``ids``.
    """
    rows: dict[str, list[int]] = {}
    for k, key in enumerate(ids):
        rows.setdefault(key, []).append(k)
    means = []
    for column in columns:
        values = np.asarray(column, dtype=np.float64)
        if len(values) != len(ids):
            raise ValueError(f"got {len(values)} rows for {len(ids)} ids")
        means.append(np.array([values[index].mean(axis=0) for index in rows.values()]))
    return tuple(rows), means
