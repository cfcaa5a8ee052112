"""Saved calibrations: the registration of a cell as a YAML file, and the forms ROS users load.

A :class:`Calibration` is the transform ``destination ≈ R @ working + t`` as tf sees it: the
pose of the **child** (working) frame in the **parent** (destination) frame, translation in
metres and rotation as a unit quaternion ``(x, y, z, w)`` (REP 103, tf2's order), with the
quality figures it was built with (the decision, σ, σ_L, the expected TRE of the transform
alone and with the decision's corrections, fiducial count) and, from a model, the ``answers``
that let a node answer targets with it (:mod:`.calibration_answers`). 2D
models are rotations about z with zero z translation. The file format is documented in
docs/CALIBRATION.md. No rclpy: numpy, scipy, PyYAML and the standard library only.
"""

from __future__ import annotations

import dataclasses
import math
import os
import shlex
import stat
import time
import uuid
from datetime import datetime, timezone
from importlib import metadata
from typing import Any, Callable, Optional

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray

from ..core.constants import INTERPOLATIONS
from ..core.frames import same_frame_problem
from ..core.rigid.quaternion import (ORTHONORMAL_TOLERANCE, matrix_from_quaternion,
                               quaternion_from_matrix)
from . import calibration_format as fields
from .calibration_answers import Answers, read_answers
from .calibration_format import FORMAT, FORMAT_VERSION, Decision

__all__ = ["Calibration", "Decision", "FORMAT", "FORMAT_VERSION", "MAX_FILE_BYTES",
           "expected_errors",
           "ORTHONORMAL_TOLERANCE", "QUATERNION_TOLERANCE", "REGISTRATIONS",
           "calibration_from_registration", "launch_snippet", "matrix_from_quaternion",
           "package_version", "quaternion_from_matrix", "read_calibration",
           "static_transform_publisher_args", "static_transform_publisher_command",
           "write_calibration"]

REGISTRATIONS = ("corrected", "uncorrected")  # which registration of the model the file holds
METHODS = ("uncorrected",) + INTERPOLATIONS    # decision.method: what targets get
QUATERNION_TOLERANCE = 1e-6     # | |q| - 1 | up to this is normalised, beyond it refused
PLANAR_TOLERANCE = 1e-9         # 2D: |qx|, |qy| [-] and |t_z| [m] at most this
#: A calibration is ~1 kB, plus ~200 bytes per fiducial of its answers (3 MB at kriging's most,
#: 15,000 fiducials); anything over 16 MiB is not one.
MAX_FILE_BYTES = 1 << 24
ANSWERS_TOLERANCE = 1e-9        # the answers' registration against the file's transform [m, -]
_ROUNDING = 8 * np.finfo(np.float64).eps  # a norm this close to 1 is unit: left as it is


@dataclasses.dataclass(frozen=True)
class Calibration:
    """A saved registration: the pose of ``child_frame`` (working) in ``parent_frame``
    (destination), i.e. ``p_parent = R(rotation) @ p_child + translation``.

    :ivar parent_frame: the destination frame (tf ``header.frame_id``), e.g. ``world``.
    :ivar child_frame: the working frame (tf ``child_frame_id``), e.g. ``tracker``.
    :ivar dimension: 2 (x, y: rotation about z, ``translation[2] == 0``) or 3.
    :ivar registration: ``corrected`` ({R_c, τ_c}) or ``uncorrected`` ({R_u, τ_u}, eq. 2).
    :ivar translation: (x, y, z) [m].
    :ivar rotation: unit quaternion (x, y, z, w); normalised on construction when its norm is
        within :data:`QUATERNION_TOLERANCE` of 1.
    :ivar fre_rms: RMS fiducial registration error of this registration [m] (root of eq. 2).
    :ivar decision: whether and how targets are corrected (:class:`Decision`).
    :ivar sigma: noise σ of one working-frame measurement, RMS over all axes [m]; None: unknown.
    :ivar sigma_axis: the same per axis, σ / √dimension [m]; None exactly when ``sigma`` is.
    :ivar sigma_l: σ_L before and after each restoration step (eq. 7) [m].
    :ivar expected_tre_rigid: expected target registration error of the transform alone, no
        corrections: the uncorrected registration's cross-validated median error [m]; None: not
        estimated (docs/CALIBRATION.md).
    :ivar expected_tre_with_corrections: expected target registration error of the points the
        decision serves, with ``decision.method``'s corrections (which need the model's
        fiducials, not in this file): its cross-validated median [m]; None: not estimated.
    :ivar n_fiducials: enabled fiducials the model was built from.
    :ivar created: when it was built, ISO 8601 in UTC (``2025-06-01T12:00:00.000000Z``).
    :ivar package_version: the rbc_registration version that built it.
    :ivar answers: what answers targets (:class:`~.calibration_answers.Answers`: the fiducials,
        their corrections, both registrations, the error model); None: the file publishes tf
        only (files of format versions 1 and 2, exports of a report).
    :raises ValueError: naming the field, when a value is not valid (see docs/CALIBRATION.md).
    """

    parent_frame: str
    child_frame: str
    dimension: int
    registration: str
    translation: tuple[float, float, float]
    rotation: tuple[float, float, float, float]
    fre_rms: float
    decision: Decision
    sigma: Optional[float]
    sigma_axis: Optional[float]
    sigma_l: tuple[float, ...]
    expected_tre_rigid: Optional[float]
    expected_tre_with_corrections: Optional[float]
    n_fiducials: int
    created: str
    package_version: str
    answers: Optional[Answers] = None

    def __post_init__(self) -> None:
        fields.check_frame("parent_frame", self.parent_frame)
        fields.check_frame("child_frame", self.child_frame)
        same = same_frame_problem("parent_frame", self.parent_frame, self.child_frame)
        if same:
            raise ValueError(f"child_frame: {same}")
        fields.check_int("dimension", self.dimension, minimum=2)
        if self.dimension not in (2, 3):
            raise ValueError(f"dimension: must be 2 or 3, got {self.dimension}")
        fields.check_choice("registration", self.registration, REGISTRATIONS)
        translation = fields.floats("translation", self.translation, "xyz",
                                    fields.MAX_ABS_COORDINATE)
        quaternion = np.array(fields.floats("rotation", self.rotation, "xyzw"))
        norm = float(np.linalg.norm(quaternion))
        if abs(norm - 1.0) > QUATERNION_TOLERANCE:
            raise ValueError(f"rotation: not a unit quaternion: its norm is {norm!r} (more than "
                             f"{QUATERNION_TOLERANCE:g} from 1)")
        if abs(norm - 1.0) > _ROUNDING:
            quaternion = quaternion / norm
        if self.dimension == 2:
            off_plane = {"rotation.x": quaternion[0], "rotation.y": quaternion[1],
                         "translation.z": translation[2]}
            for name, value in off_plane.items():
                if abs(value) > PLANAR_TOLERANCE:
                    raise ValueError(f"{name}: a 2D calibration is a rotation about z with z "
                                     f"translation 0; got {name} = {value!r}")
        object.__setattr__(self, "translation", translation)
        object.__setattr__(self, "rotation", tuple(float(v) for v in quaternion))
        fields.check_length("fre_rms", self.fre_rms)
        if not isinstance(self.decision, Decision):
            raise ValueError(f"decision: must be a Decision, got {type(self.decision).__name__}")
        fields.check_choice("decision.method", self.decision.method, METHODS)
        if self.decision.apply and self.decision.method == "uncorrected":
            raise ValueError("decision.apply: true needs a correcting method (one of "
                             f"{', '.join(INTERPOLATIONS)}), got method 'uncorrected'")
        self._check_sigma()
        object.__setattr__(self, "sigma_l", tuple(
            fields.check_length(f"sigma_L[{k}]", v) for k, v in
            enumerate(fields.sequence("sigma_L", self.sigma_l))))
        fields.optional_length("expected_tre_rigid", self.expected_tre_rigid)
        fields.optional_length("expected_tre_with_corrections",
                               self.expected_tre_with_corrections)
        fields.check_int("n_fiducials", self.n_fiducials, minimum=self.dimension)
        object.__setattr__(self, "created", fields.utc_time("created", self.created))
        fields.check_text("package_version", self.package_version)
        if self.answers is not None:
            self._check_answers()

    def _check_answers(self) -> None:
        """The answers belong to this file: its dimension, fiducial count, method and transform,
        with kriging's hyper-parameters where the answers need them."""
        a = self.answers
        if not isinstance(a, Answers):
            raise ValueError(f"answers: must be an Answers record, got {type(a).__name__}")
        if a.dimension != self.dimension:
            raise ValueError(f"answers: fiducials of dimension {a.dimension} in a "
                             f"{self.dimension}D calibration")
        if len(a.ids) != self.n_fiducials:
            raise ValueError(f"answers.fiducials: {len(a.ids)} fiducials, but n_fiducials is "
                             f"{self.n_fiducials}")
        if a.method != self.decision.method:
            raise ValueError(f"answers.error_model: of the method {a.method!r}, but "
                             f"decision.method is {self.decision.method!r}")
        if "kriging" in a.needs() and a.kriging is None:
            raise ValueError("answers.kriging: null, but the answers need kriging (interpolation "
                             "kriging, decision.method kriging or a scaled error model)")
        rotation, translation = a.registration(self.registration)
        d = self.dimension
        off = max(float(np.max(np.abs(rotation - self.rotation_matrix()[:d, :d]))),
                  float(np.max(np.abs(translation - np.array(self.translation[:d])))
                        / max(1.0, float(np.max(np.abs(translation))))))
        if off > ANSWERS_TOLERANCE:
            raise ValueError(f"answers.{self.registration}: differs from translation/rotation by "
                             f"{off:.3g} (more than {ANSWERS_TOLERANCE:g}): not this file's "
                             f"registration")

    def _check_sigma(self) -> None:
        if (self.sigma is None) != (self.sigma_axis is None):
            raise ValueError("sigma_axis: must be null exactly when sigma is null, got "
                             f"sigma = {self.sigma!r}, sigma_axis = {self.sigma_axis!r}")
        if self.sigma is None:
            return
        sigma = fields.check_length("sigma", self.sigma)
        axis = fields.check_length("sigma_axis", self.sigma_axis)
        expected = sigma / math.sqrt(self.dimension)
        if not math.isclose(axis, expected, rel_tol=1e-9, abs_tol=1e-300):
            raise ValueError(f"sigma_axis: must be sigma / sqrt(dimension) = {expected!r}, "
                             f"got {axis!r}")

    def rotation_matrix(self) -> NDArray[np.float64]:
        """R (3, 3): ``p_parent = R @ p_child + translation``."""
        return matrix_from_quaternion(self.rotation)

    def transform_matrix(self) -> NDArray[np.float64]:
        """The homogeneous transform (4, 4) from child (working) to parent (destination)."""
        m = np.eye(4)
        m[:3, :3] = self.rotation_matrix()
        m[:3, 3] = self.translation
        return m

    def to_mapping(self) -> dict[str, Any]:
        """The file's content (docs/CALIBRATION.md), keys in file order."""
        return fields.to_mapping(self)


def calibration_from_registration(
        rotation: ArrayLike, translation: ArrayLike, *, parent_frame: str, child_frame: str,
        registration: str, fre_rms: float, decision: Decision, sigma: Optional[float],
        sigma_l: ArrayLike, expected_tre_rigid: Optional[float],
        expected_tre_with_corrections: Optional[float], n_fiducials: int,
        clock: Callable[[], float] = time.time,
        version: Optional[str] = None, answers: Optional[Answers] = None) -> Calibration:
    """A :class:`Calibration` of the registration ``destination ≈ rotation @ working +
    translation`` (a :class:`~rbc_registration.core.rigid.registration.Registration`'s fields).

    :param rotation: R, (3, 3), or (2, 2) for a 2D model (embedded as a rotation about z).
    :param translation: t [m], (3,), or (2,) for a 2D model (z = 0).
    :param parent_frame: the destination frame.
    :param child_frame: the working frame.
    :param sigma: σ [m] (RMS of a point, all axes) or None; ``sigma_axis`` = σ / √d.
    :param clock: seconds since the epoch (UTC) for ``created``.
    :param version: the package version (default: :func:`package_version`).
    :param answers: what answers targets (:func:`~.calibration_answers.answers_of_model`), or
        None.
    :raises ValueError: as :class:`Calibration` and :func:`quaternion_from_matrix`.
    """
    r = np.asarray(rotation, dtype=np.float64)
    t = np.asarray(translation, dtype=np.float64)
    dimension = len(r) if r.ndim == 2 else 0
    if t.shape != (dimension,):
        raise ValueError(f"translation must have shape ({dimension},) for a {r.shape} "
                         f"rotation, got {t.shape}")
    t3 = np.zeros(3)
    t3[:dimension] = t
    sigma_axis = None if sigma is None else float(sigma) / math.sqrt(dimension)
    created = datetime.fromtimestamp(clock(), tz=timezone.utc)
    return Calibration(
        parent_frame=parent_frame, child_frame=child_frame, dimension=dimension,
        registration=registration, translation=tuple(float(v) + 0.0 for v in t3),
        rotation=quaternion_from_matrix(r), fre_rms=float(fre_rms), decision=decision,
        sigma=None if sigma is None else float(sigma), sigma_axis=sigma_axis,
        sigma_l=tuple(float(v) for v in np.ravel(np.asarray(sigma_l, dtype=np.float64))),
        expected_tre_rigid=None if expected_tre_rigid is None else float(expected_tre_rigid),
        expected_tre_with_corrections=None if expected_tre_with_corrections is None
        else float(expected_tre_with_corrections),
        n_fiducials=int(n_fiducials),
        created=created.isoformat(timespec="microseconds").replace("+00:00", "Z"),
        package_version=package_version() if version is None else version, answers=answers)


def package_version() -> str:
    """The installed rbc_registration version (``unknown`` when run from an uninstalled tree)."""
    try:
        return metadata.version("rbc_registration")
    except metadata.PackageNotFoundError:
        return "unknown"


def static_transform_publisher_args(cal: Calibration) -> list[str]:
    """The arguments of tf2_ros's ``static_transform_publisher`` (flag syntax of Humble and later,
    as in Kilted) that publish ``cal`` on /tf_static: parent = ``--frame-id``."""
    (x, y, z), (qx, qy, qz, qw) = cal.translation, cal.rotation
    numbers = [("--x", x), ("--y", y), ("--z", z), ("--qx", qx), ("--qy", qy), ("--qz", qz),
               ("--qw", qw)]
    args = [item for flag, value in numbers for item in (flag, repr(value + 0.0))]
    return args + ["--frame-id", cal.parent_frame, "--child-frame-id", cal.child_frame]


def static_transform_publisher_command(cal: Calibration) -> str:
    """The shell line ``ros2 run tf2_ros static_transform_publisher --x ... --child-frame-id ...``
    (frames shell-quoted where needed)."""
    return shlex.join(["ros2", "run", "tf2_ros", "static_transform_publisher",
                       *static_transform_publisher_args(cal)])


def launch_snippet(cal: Calibration) -> str:
    """A Python launch file action publishing ``cal`` with ``static_transform_publisher``."""
    args = static_transform_publisher_args(cal)
    pairs = ",\n".join(f"        {args[k]!r}, {args[k + 1]!r}" for k in range(0, len(args), 2))
    return ("from launch_ros.actions import Node\n\n"
            f"# {cal.child_frame} in {cal.parent_frame}: calibration of {cal.created}\n"
            "Node(\n"
            "    package='tf2_ros',\n"
            "    executable='static_transform_publisher',\n"
            "    arguments=[\n"
            f"{pairs},\n"
            "    ],\n"
            ")\n")


def expected_errors(cal: Calibration) -> str:
    """One line saying what each expected TRE of ``cal`` is: the transform alone
    (``expected_tre_rigid``), and with the decision's corrections, which the file does not hold
    (``expected_tre_with_corrections``)."""
    def mm(v: Optional[float]) -> str:
        return "not estimated" if v is None else f"{v * 1e3:.4g} mm"

    line = f"expected target error: {mm(cal.expected_tre_rigid)} with this transform alone " \
           f"(expected_tre_rigid)"
    if cal.decision.method in INTERPOLATIONS:
        where = ("from this file's answers too" if cal.answers is not None
                 else "not in this file")
        line += (f"; {mm(cal.expected_tre_with_corrections)} only with the model's "
                 f"{cal.decision.method} corrections of each target (expected_tre_with_"
                 f"corrections: the node's ~/correct_targets; {where})")
    return line


def write_calibration(path: str, cal: Calibration) -> None:
    """Write ``cal`` to ``path`` as YAML, atomically: a temporary file with a unique name in the
    same directory, fsync, rename over ``path``, fsync of the directory. A reader sees the old
    file or the new one, never a mix; on failure ``path`` is unchanged.

    :raises OSError: when it cannot be written (the temporary file is removed).
    """
    header = ("# rbc_registration calibration (docs/CALIBRATION.md): the pose of child_frame in\n"
              "# parent_frame, p_parent = R(rotation) p_child + translation; metres, REP 103.\n"
              f"# {static_transform_publisher_command(cal)}\n"
              "# expected_tre_rigid: this transform alone; expected_tre_with_corrections: only\n"
              "# with decision.method's corrections of each target, held in answers "
              "(null: none).\n")
    text = header + yaml.safe_dump(cal.to_mapping(), sort_keys=False, allow_unicode=True,
                                   default_flow_style=None, width=100)
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    tmp = os.path.join(directory, f".{os.path.basename(path)}.{os.getpid()}."
                                  f"{uuid.uuid4().hex}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o644)
        with os.fdopen(fd, "wb") as f:
            f.write(text.encode("utf-8"))
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.lexists(tmp):
            os.unlink(tmp)
        raise
    dir_fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def read_calibration(path: str) -> Calibration:
    """Read and validate a calibration file written by :func:`write_calibration` (or by hand).

    :raises ValueError: one line naming ``path`` and what is wrong: not a readable regular file,
        over :data:`MAX_FILE_BYTES`, not UTF-8 YAML, another format, or a field missing, unknown,
        of the wrong type or out of range (e.g. ``cal.yaml: rotation.w: missing``).
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)  # a FIFO must not block
    except OSError as exc:
        raise ValueError(f"{path}: cannot be read: {exc.strerror}") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise ValueError(f"{path}: not a regular file")
        raw = b""
        while len(raw) <= MAX_FILE_BYTES:  # a read may return less than asked: read to EOF
            chunk = os.read(fd, MAX_FILE_BYTES + 1 - len(raw))
            if not chunk:
                break
            raw += chunk
    except OSError as exc:
        raise ValueError(f"{path}: cannot be read: {exc.strerror}") from None
    finally:
        os.close(fd)
    if len(raw) > MAX_FILE_BYTES:
        raise ValueError(f"{path}: larger than {MAX_FILE_BYTES} bytes: not a calibration file")
    try:
        data = fields.load_yaml(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text (byte {exc.start})") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or type(exc).__name__
        raise ValueError(f"{path}: not valid YAML{where}: {problem}") from None
    except RecursionError:
        raise ValueError(f"{path}: not valid YAML: nested too deeply") from None
    if data is None:
        raise ValueError(f"{path}: empty (no YAML document): not a calibration file")
    try:
        kwargs = fields.from_mapping(data)
        if kwargs["answers"] is not None:
            dimension, method = kwargs["dimension"], kwargs["decision"].method
            if dimension not in (2, 3):       # the record says so, naming the field
                return Calibration(**{**kwargs, "answers": None})
            kwargs["answers"] = read_answers(kwargs["answers"], dimension, method)
        return Calibration(**kwargs)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
