"""The ``answers`` section of a calibration file (docs/CALIBRATION.md): what a publish-only node
needs to answer ``~/correct_target(s)`` as the live model did: the configured interpolation,
both registrations, the decision's error model, kriging's hyper-parameters and the fiducials
(id, working-frame mean, correction ε, repeat count). Metres, working frame.

:class:`Answers` is the validated record; :func:`answers_of_model` takes it from a built
model, :func:`read_answers` from the parsed YAML, :meth:`Answers.to_mapping` writes it, and
:meth:`Answers.model` builds the :class:`~rbc_registration.core.saved_model.SavedModel`. No rclpy.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Optional

import numpy as np

from ..core.constants import INTERPOLATIONS
from ..core.decision.choice import ErrorModel
from ..core.interpolation.kriging import KrigingHyperparameters
from ..core.model import RbcModel
from ..core.rigid.quaternion import quaternion_from_matrix
from ..core.rigid.registration import Registration
from ..core.saved_model import ModelParts, SavedModel, needed_interpolations, saved_model
from ..core.validation import MAX_ABS_COORDINATE
from . import calibration_format as fields

__all__ = ["ANSWERS_KEYS", "Answers", "answers_of_model", "read_answers"]

ANSWERS_KEYS = ("interpolation", "uncorrected", "corrected", "error_model", "kriging",
                "fiducials")
REGISTRATION_KEYS = ("rotation", "translation")
ERROR_MODEL_KEYS = ("scaled", "median_factor", "bound_factor", "level", "scale_floor")
KRIGING_KEYS = ("signal_std", "length_scale", "noise_std", "noise_fitted")
FIDUCIAL_KEYS = ("id", "working", "correction", "repeats")
_AXES = "xyz"

Matrix = tuple[tuple[float, ...], ...]


@dataclasses.dataclass(frozen=True)
class Answers:
    """The parts of a model that answer targets (module docstring), metres.

    :ivar interpolation: the configured interpolation (``corrected``, ``correction``).
    :ivar uncorrected: {R_u, τ_u} as (rotation rows, translation), d x d and d.
    :ivar corrected: {R_c, τ_c} as the same.
    :ivar error_model: the decision's :class:`~rbc_registration.core.decision.choice.ErrorModel`
        (NaN factors: no cross-validation was possible).
    :ivar kriging: kriging's hyper-parameters, None when kriging was not built.
    :ivar ids: the fiducial ids; ``working``, ``corrections`` (d each) and ``repeats`` per id.
    """

    interpolation: str
    uncorrected: tuple[Matrix, tuple[float, ...]]
    corrected: tuple[Matrix, tuple[float, ...]]
    error_model: ErrorModel
    kriging: Optional[KrigingHyperparameters]
    ids: tuple[str, ...]
    working: Matrix
    corrections: Matrix
    repeats: tuple[int, ...]

    @property
    def dimension(self) -> int:
        """d of the fiducials (2 or 3)."""
        return len(self.working[0])

    def registration(self, which: str) -> tuple[np.ndarray, np.ndarray]:
        """``(R, t)`` of ``uncorrected`` or ``corrected`` as arrays."""
        rows, t = getattr(self, which)
        return np.array(rows, dtype=np.float64), np.array(t, dtype=np.float64)

    @property
    def method(self) -> str:
        """The decision's method (the file's ``decision.method``)."""
        return self.error_model.method

    def needs(self) -> tuple[str, ...]:
        """The interpolations the answers evaluate."""
        return needed_interpolations(self.interpolation, self.method, self.error_model.scaled)

    def model(self, sigma: Optional[float]) -> SavedModel:
        """The model answering, with σ of the file.

        :raises ValueError: as :func:`~rbc_registration.core.saved_model.saved_model`.
        """
        regs = [Registration(*self.registration(w), math.nan)
                for w in ("uncorrected", "corrected")]
        return saved_model(ModelParts(
            self.ids, np.array(self.working, dtype=np.float64),
            np.array(self.corrections, dtype=np.float64),
            np.array(self.repeats, dtype=np.int64), regs[0], regs[1], self.interpolation,
            self.method, self.error_model, sigma, self.kriging))

    def to_mapping(self) -> dict[str, Any]:
        """The section as written (keys in file order; NaN factors as null)."""
        e = self.error_model

        def num(v: float) -> Optional[float]:
            return v if math.isfinite(v) else None

        return {
            "interpolation": self.interpolation,
            **{w: {"rotation": [list(row) for row in getattr(self, w)[0]],
                   "translation": list(getattr(self, w)[1])}
               for w in ("uncorrected", "corrected")},
            "error_model": {"scaled": e.scaled, "median_factor": num(e.median_factor),
                            "bound_factor": num(e.bound_factor), "level": e.level,
                            "scale_floor": e.scale_floor},
            "kriging": None if self.kriging is None else self.kriging._asdict(),
            "fiducials": [{"id": i, "working": list(w), "correction": list(c), "repeats": n}
                          for i, w, c, n in zip(self.ids, self.working, self.corrections,
                                                self.repeats)],
        }


def _floats(values: Any) -> tuple[float, ...]:
    return tuple(float(v) + 0.0 for v in np.ravel(np.asarray(values, dtype=np.float64)))


def _registration(reg: Registration) -> tuple[Matrix, tuple[float, ...]]:
    return (tuple(_floats(row) for row in np.atleast_2d(reg.rotation)), _floats(reg.translation))


def answers_of_model(model: RbcModel) -> Answers:
    """The :class:`Answers` of a built model (its numbers as they are: a round trip through the
    file gives them back bit for bit)."""
    return Answers(
        interpolation=model.config.interpolation,
        uncorrected=_registration(model.uncorrected), corrected=_registration(model.corrected),
        error_model=model.decision.error_model, kriging=model.kriging_hyperparameters,
        ids=tuple(model.ids), working=tuple(_floats(row) for row in model.working),
        corrections=tuple(_floats(row) for row in model.corrections),
        repeats=tuple(int(n) for n in model.counts))


def _points(name: str, value: Any, d: int) -> tuple[float, ...]:
    return fields.floats(name, value, _AXES[:d], MAX_ABS_COORDINATE)


def _read_registration(name: str, value: Any, d: int) -> tuple[Matrix, tuple[float, ...]]:
    data = fields._mapping(name, value, REGISTRATION_KEYS)
    rows = fields.sequence(f"{name}.rotation", data["rotation"])
    if len(rows) != d:
        raise ValueError(f"{name}.rotation: must have {d} rows (dimension {d}), got {len(rows)}")
    matrix = tuple(fields.floats(f"{name}.rotation[{k}]", row, _AXES[:d])
                   for k, row in enumerate(rows))
    try:
        quaternion_from_matrix(matrix)
    except ValueError as exc:
        raise ValueError(f"{name}.rotation: {exc}") from None
    return matrix, _points(f"{name}.translation", data["translation"], d)


def _read_error_model(value: Any, method: str) -> ErrorModel:
    data = fields._mapping("answers.error_model", value, ERROR_MODEL_KEYS)
    if not isinstance(data["scaled"], bool):
        raise ValueError(f"answers.error_model.scaled: must be true or false, got "
                         f"{fields._quote(data['scaled'])}")
    factors = []
    for key in ("median_factor", "bound_factor"):
        v = data[key]
        factors.append(math.nan if v is None else
                       fields.check_length(f"answers.error_model.{key}", v))
    level = fields.check_number("answers.error_model.level", data["level"])
    if not 0.0 < level < 1.0:
        raise ValueError(f"answers.error_model.level: must be in (0, 1), got {level!r}")
    floor = fields.check_length("answers.error_model.scale_floor", data["scale_floor"])
    return ErrorModel(method, data["scaled"], factors[0], factors[1], level, floor)


def _read_kriging(value: Any) -> Optional[KrigingHyperparameters]:
    if value is None:
        return None
    data = fields._mapping("answers.kriging", value, KRIGING_KEYS)
    numbers = [fields.check_length(f"answers.kriging.{k}", data[k]) for k in KRIGING_KEYS[:3]]
    if not numbers[0] > 0 or not numbers[1] > 0:
        raise ValueError("answers.kriging: signal_std and length_scale must be > 0, got "
                         f"{numbers[0]!r} and {numbers[1]!r}")
    if not isinstance(data["noise_fitted"], bool):
        raise ValueError(f"answers.kriging.noise_fitted: must be true or false, got "
                         f"{fields._quote(data['noise_fitted'])}")
    return KrigingHyperparameters(*numbers, data["noise_fitted"])


def read_answers(value: Any, dimension: int, method: str) -> Answers:
    """The :class:`Answers` of the parsed ``answers`` mapping of a ``dimension``-D file whose
    ``decision.method`` is ``method``.

    :raises ValueError: naming the field (``answers.fiducials[3].working.y: missing`` ...).
    """
    data = fields._mapping("answers", value, ANSWERS_KEYS)
    d = dimension
    interpolation = fields.check_choice("answers.interpolation", data["interpolation"],
                                        INTERPOLATIONS)
    rows = fields.sequence("answers.fiducials", data["fiducials"])
    if len(rows) < d + 1:
        raise ValueError(f"answers.fiducials: at least {d + 1} in {d}D, got {len(rows)}")
    ids, working, corrections, repeats = [], [], [], []
    for k, row in enumerate(rows):
        at = f"answers.fiducials[{k}]"
        f = fields._mapping(at, row, FIDUCIAL_KEYS)
        ids.append(fields.check_text(f"{at}.id", f["id"]))
        working.append(_points(f"{at}.working", f["working"], d))
        corrections.append(_points(f"{at}.correction", f["correction"], d))
        repeats.append(fields.check_int(f"{at}.repeats", f["repeats"], minimum=1))
    if len(set(ids)) != len(ids):
        twice = next(i for i in ids if ids.count(i) > 1)
        raise ValueError(f"answers.fiducials: the id {fields._quote(twice)} is given twice")
    return Answers(
        interpolation=interpolation,
        uncorrected=_read_registration("answers.uncorrected", data["uncorrected"], d),
        corrected=_read_registration("answers.corrected", data["corrected"], d),
        error_model=_read_error_model(data["error_model"], method),
        kriging=_read_kriging(data["kriging"]), ids=tuple(ids), working=tuple(working),
        corrections=tuple(corrections), repeats=tuple(repeats))
