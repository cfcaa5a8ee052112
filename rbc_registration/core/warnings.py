"""The warnings of a built model, one line each: one definition for the CLI, the node and the
recorded-bag path (each adds only what it alone knows, e.g. the CLI a cell too large for its
unit)."""

from __future__ import annotations

from typing import Optional, Sequence

from .decision.evaluation import blunders, describe_blunders
from .decision.groups import undeclared_groups
from .model import RbcModel
from .decision.noise import identical_repeats, scattered_repeats
from .repeats import describe_twins, twin_groups
from .rigid.scale import rigidity_warnings


def model_warnings(model: RbcModel, unit: str,
                   first_stamps: Optional[Sequence[float]] = None) -> list[str]:
    """Frames that do not match rigidly or an unconverged restoration
    (:func:`~.scale.rigidity_warnings`), repeats that scatter or are all identical
    (:mod:`.noise`), a fiducial whose held-out error stands out (:func:`~.evaluation.blunders`),
    one point under two ids (:func:`~.repeats.twin_groups`) and, when no groups were given,
    fiducials that look grouped (:func:`~.groups.undeclared_groups`).

    :param unit: the unit named in the lines (``m`` in ROS).
    :param first_stamps: the stamp of each fiducial's first measurement [s], if known.
    :return: the lines, in that order (empty ones left out).
    """
    twins = describe_twins(model.ids, model.working,
                           twin_groups(model.working, model.destination), unit)
    grouped = (undeclared_groups(model.ids, model.working, first_stamps)
               if model.groups is None else "")
    return [line for line in (*rigidity_warnings(model, unit),
                              scattered_repeats(model.ids, model.repeat_stats, unit),
                              identical_repeats(model.repeat_stats, model.sigma_source),
                              describe_blunders(blunders(model), unit), twins, grouped) if line]
