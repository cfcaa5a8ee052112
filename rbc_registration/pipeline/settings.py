"""Settings of the pipeline, i.e. the parameters of ``registration_node`` and of ``evaluate -p``:
the table of names, defaults, ranges and descriptions, their validation and the immutable
:class:`Settings` snapshot. Pure Python (no numpy, no rclpy); the node declares them as ROS
parameters in :func:`rbc_registration.ros.params.declare`.

Units: metres and seconds (REP 103). msg_docs/README.md renders the same table.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from functools import cached_property
from typing import Any, Mapping, NamedTuple, Optional

from ..core.constants import (DECISION_MODES, INTERPOLATIONS, MAX_RESTORATION_STEPS,
                               RESTORATIONS, DecisionMode, rho_thresholds_error)
from ..core.frames import frame_id_problem, same_frame_problem
from ..core.measurements.records import quote
from .named import (calibration_name_problem, is_calibration_name, parse_target_frames,
                    target_frames_problem)
from .state_dir import StateDir


class Spec(NamedTuple):
    """One parameter: default value, description, whether it is read-only after start, the
    closed range ``(low, high)`` of a number, whether ``low`` itself is excluded, the allowed
    strings, and whether it changes the model built from the same fiducials (the start's
    warning about a snapshot built with other parameters names only those). A tuple default
    is a list of strings (a ROS string array)."""

    default: Any
    description: str
    read_only: bool = False
    low: Optional[float] = None
    high: Optional[float] = None
    low_exclusive: bool = False
    choices: tuple[str, ...] = ()
    changes_model: bool = False


TF_MODES = ("corrected", "uncorrected", "none")
RELIABILITIES = ("reliable", "best_effort")
#: ``state_dir`` value meaning "derived from the node's namespace and name"
#: (:func:`rbc_registration.pipeline.state_dir.default_state_dir`).
STATE_DIR_AUTO = "auto"
POINT_MODES = ("pair", "sample")      # point_mode: pair points by stamp, or on ~/take_sample only
SAMPLE_SOURCES = ("topic", "tf")      # sample_destination_source
REBUILD_WORKERS = ("auto", "thread", "process")  # rebuild_worker (pipeline.build_process)
#: ``rebuild_worker: auto`` builds in the child process from this many enabled fiducials on (a
#: kriging build at J = 1,000 takes about 1 s on a 2-core machine, the child's start 1-1.7 s once).
PROCESS_MIN_FIDUCIALS = 1000

#: Parameters that were removed, with what replaces them (the reason given when one is set).
REMOVED = {"apply_corrections": "it was replaced by 'decision' (auto -> rho for the paper's "
                                "rule, or cv, the default; on -> on; off -> off)"}

SPECS: dict[str, Spec] = {
    "working_frame": Spec("tracker", "Frame the working points (fiducials, targets) are measured "
                          "in, e.g. the tracker. Read-only.", read_only=True),
    "destination_frame": Spec("world", "Frame the registration maps into, e.g. the robot base or "
                              "world. Read-only.", read_only=True),
    "dimension": Spec(3, "3, or 2 to register x, y only as in the paper (z of a target is "
                      "passed through unchanged). Read-only.", read_only=True, low=2, high=3,
                      changes_model=True),
    "restoration": Spec("iterative", "How the rigid-body condition is restored: 'iterative' "
                        "(the paper's steps) or 'closed-form'.", choices=RESTORATIONS,
                        changes_model=True),
    "restoration_steps": Spec(2, "Steps of the iterative restoration (the paper uses 2).",
                              low=1, high=MAX_RESTORATION_STEPS, changes_model=True),
    "interpolation": Spec("paper", "Interpolation of the fiducial corrections at a target "
                          "(paper eq. 5): 'paper' or 'kriging'.", choices=INTERPOLATIONS,
                          changes_model=True),
    "sigma": Spec(0.0, "Known noise sigma [m] of one working-frame measurement, in the sense of "
                  "the sigma estimated from repeats (RMS distance of a measurement from the "
                  "fiducial's mean, all axes together; per axis it is sigma / sqrt(dimension)); "
                  "the paper's rho = sigma_L0 / sigma uses it (pure noise: rho = sqrt(2 / "
                  "dimension)). 0 = unknown: estimated from fiducials measured >= 2 times. "
                  "Give sigma or sigma_axis, not both.", low=0.0, high=1.0,
                  changes_model=True),
    "sigma_axis": Spec(0.0, "Known noise [m] per axis of one working-frame measurement "
                       "(sigma = sigma_axis * sqrt(dimension); a 0.11 mm 'per axis' spec is "
                       "sigma_axis 0.00011). 0 = unknown. Give sigma or sigma_axis, not both.",
                       low=0.0, high=1.0, changes_model=True),
    "decision": Spec(DecisionMode.CV.value, "Whether and how targets get corrections: 'cv' "
                     "(cross-validated on the fiducials, needs no sigma: a correction is applied "
                     "only when it predicts held-out fiducials better than the uncorrected "
                     "registration with 95 % confidence), 'rho' (the paper's rule on rho, needs "
                     "sigma), 'on' (always the configured interpolation), 'off' (never). rho is "
                     "reported in every mode.", choices=DECISION_MODES,
                     changes_model=True),
    "kriging_warm_start": Spec(False, "Start each rebuild's kriging fit from the served "
                               "model's hyper-parameters (faster when few fiducials changed). "
                               "Off by default: a warm-started fit ends within the optimiser's "
                               "tolerance of a cold one, not bit for bit, so a restart from the "
                               "journal (always a cold fit) would answer ~1e-13 m differently."),
    "rho_reject": Spec(1.0, "rho = sigma_L0 / sigma below this: the paper's rule says do not "
                       "correct (paper: rho < 1 makes registration worse). Must be <= "
                       "rho_apply.", low=0.0, high=1e6, changes_model=True),
    "rho_apply": Spec(2.5, "rho at or above this: the paper's rule says correct (decision "
                      "'rho'; paper: rho >= 2.5 is beneficial).", low=0.0, high=1e6,
                      changes_model=True),
    "min_fiducials": Spec(4, "Enabled fiducials needed before a model is built.",
                          low=3, high=1_000_000, changes_model=True),
    "pair_slop": Spec(0.02, "Largest stamp difference [s] between a ~/working_point and a "
                      "~/destination_point to pair them.", low=0.0, high=10.0, low_exclusive=True),
    "merge_radius": Spec(0.005, "A pair without an id joins the fiducial whose mean "
                         "destination point is nearest within this distance [m], else a new "
                         "auto-NNNN fiducial.", low=0.0, high=10.0, low_exclusive=True),
    "outlier_distance": Spec(0.01, "A measurement farther than this [m] from the mean of its "
                             "fiducial's earlier repeats (either frame) is rejected; and when a "
                             "model cannot be built, fiducials whose distances to the others "
                             "differ between the frames by more than this and 20x the "
                             "fiducials' median are left out of it, named in ~/status; 0 = off.",
                             low=0.0, high=100.0, changes_model=True),
    "max_stamp_age": Spec(0.0, "A measurement whose header stamp is more than this [s] older "
                          "than the node clock, or more than this ahead of it, is rejected as "
                          "stale; 0 = off (so a bag replayed with its old stamps is accepted).",
                          low=0.0, high=1e9),
    "max_targets": Spec(10_000, "Most targets in one ~/correct_targets request; a larger "
                        "request is refused with success=false (CorrectTargets holds at most "
                        "100,000: a client cannot send more).", low=1, high=100_000),
    "debounce_period": Spec(0.2, "Recompute once no measurement arrived for this long [s] "
                            "(at the latest 10x this after the first pending one).",
                            low=0.0, high=60.0),
    "rebuild_worker": Spec("auto", "Where the node builds a model: 'process' (a child Python "
                           "process with its own GIL, so a long rebuild does not slow the "
                           "services), 'thread' (the recompute thread of the node's process) or "
                           f"'auto' (the process from {PROCESS_MIN_FIDUCIALS} enabled fiducials "
                           "on, the thread below).", choices=REBUILD_WORKERS),
    "point_buffer": Spec(100, "Unmatched ~/working_point or ~/destination_point messages kept "
                         "per stream for pairing. Read-only.", read_only=True, low=1,
                         high=100_000),
    "input_reliability": Spec("reliable", "QoS reliability of the three input topics: "
                              "'reliable' (KEEP_ALL: a burst makes the publisher wait, nothing is "
                              "dropped) or 'best_effort' (matches best-effort driver publishers; "
                              "depth 1000). Read-only.", read_only=True, choices=RELIABILITIES),
    "input_batch": Spec(16, "Most messages taken from one input topic per wake-up of the "
                        "executor: after the message the executor hands over, up to "
                        "input_batch - 1 more already queued ones, in order (rclpy takes one per "
                        "wake-up and rebuilds its wait set each time, which dominated a burst). "
                        "A ready service call or timer waits at most one batch; 1 = one message "
                        "per wake-up.", low=1, high=100_000),
    "state_dir": Spec(STATE_DIR_AUTO, "Directory of the measurement journal, the calibration "
                      "snapshot and saved calibrations ('~' expanded); 'auto' = "
                      "$ROS_HOME/rbc_registration/<namespace tokens>.<node name> ($ROS_HOME "
                      "default ~/.ros), one per node; empty = no persistence. Read-only.",
                      read_only=True),
    "calibration_file": Spec("", "Calibration YAML (docs/CALIBRATION.md) loaded at start and "
                             "published on ~/transform (registration corrected) or "
                             "~/transform_uncorrected (uncorrected) and /tf_static until a live "
                             "model is built, answering ~/correct_target(s) from its answers; "
                             "its frames and dimension must be the node's; a bare NAME (no '/', "
                             "no .yaml) is state_dir/calibrations/NAME.yaml; empty = none. "
                             "Read-only.", read_only=True),
    "calibration_name": Spec("", "Name of the calibration ~/save writes: "
                             "state_dir/calibrations/NAME.yaml (loaded again with "
                             "calibration_file:=NAME); empty = state_dir/calibration.yaml. "
                             "Letters, digits, '_', '-', '.'."),
    "target_frames": Spec((), "Named targets published on /tf_static as corrected destination "
                          "frames: a list of 'NAME:X,Y,Z' (X, Y, Z [m] in working_frame); each "
                          "is a child frame NAME of destination_frame at the target's "
                          "~/correct_target destination, replaced with every model; empty = "
                          "none."),
    "journal_fsync": Spec(False, "fsync the journal after every record (survives power loss; "
                          "slower). Default: flush to the OS per record (survives SIGKILL). "
                          "Read-only.", read_only=True),
    "stale_after": Spec(30.0, "/diagnostics warns when accepted measurements have waited "
                        "longer than this [s] without entering the model (a stale model).",
                        low=0.0, high=1e6, low_exclusive=True),
    "status_period": Spec(1.0, "Period [s] of ~/status and /diagnostics besides each "
                          "recompute, on the steady clock (with use_sim_time too). Read-only.",
                          read_only=True, low=0.01, high=3600.0),
    "tf_broadcast": Spec("corrected", "Which registration the node's own /tf_static entry "
                         "holds (replaced on every model): 'corrected', 'uncorrected' or 'none' "
                         "(no entry).",
                         choices=TF_MODES),
    "point_mode": Spec("pair", "'pair': a ~/working_point and a ~/destination_point whose "
                       "stamps are within pair_slop are one measurement; 'sample': the points "
                       "only update the latest ones, recorded on ~/take_sample.",
                       choices=POINT_MODES),
    "sample_max_age": Spec(1.0, "~/take_sample refuses a latest working or destination point "
                           "received longer ago than this [s] (node clock).", low=0.0,
                           high=1e6, low_exclusive=True),
    "sample_destination_source": Spec("topic", "Destination point of ~/take_sample: 'topic' "
                                      "(the latest ~/destination_point) or 'tf' (the origin of "
                                      "sample_tf_child in sample_tf_parent, looked up now; needs "
                                      "tf2_ros).", choices=SAMPLE_SOURCES),
    "sample_tf_parent": Spec("", "tf frame the destination point of a tf sample is expressed "
                             "in; empty = destination_frame, the one other value accepted."),
    "sample_tf_child": Spec("", "tf frame whose origin is the destination point of a tf sample "
                            "(e.g. the robot TCP or the tracker target); must be set for 'tf'."),
    "marker_scale": Spec(0.01, "Diameter [m] of the fiducial spheres in ~/markers.",
                         low=0.0, high=10.0, low_exclusive=True),
    "marker_arrow_gain": Spec(100.0, "Correction arrows in ~/markers are drawn this many times "
                              "longer than the correction (dimensionless).", low=0.0, high=1e6),
    "max_markers": Spec(1000, "Most correction arrows and disabled-fiducial labels in "
                        "~/markers (the sphere lists hold every fiducial); with more, the "
                        "arrows of the largest corrections are drawn.", low=0, high=1_000_000),
    "max_candidates": Spec(500, "Most candidates, and most targets, in one ~/suggest_next "
                           "request; a larger request is refused with success=false (bounds "
                           "the time a plan holds the executor).", low=1, high=100_000),
    "plan_within": Spec(0.10, "~/suggest_next says enough when the expected median target "
                        "error is within this fraction of what measuring every candidate is "
                        "expected to give (dimensionless); 0 = off.", low=0.0, high=10.0),
    "plan_min_gain_fraction": Spec(0.0, "... or when the best candidate (or group) is expected "
                                   "to reduce the median target error by less than this "
                                   "fraction of it (dimensionless); 0 = off.", low=0.0,
                                   high=0.99),
    "plan_min_gain_length": Spec(0.0, "... or by less than this [m]; 0 = off.", low=0.0,
                                 high=1.0),
    "plan_max_fiducials": Spec(1000, "Above this many fiducials the planner is off "
                               "(~/status expected_target_error NaN, ~/suggest_next refused): "
                               "its expected error is O(J^3), and without a kriging model (e.g. "
                               "decision off) it fits the kriging hyper-parameters first.",
                               low=3, high=100_000),
}


@dataclass(frozen=True)
class Settings:
    """An immutable snapshot of all parameters (see :data:`SPECS` for meanings and units)."""

    working_frame: str
    destination_frame: str
    dimension: int
    restoration: str
    restoration_steps: int
    interpolation: str
    sigma: float
    sigma_axis: float
    decision: str
    kriging_warm_start: bool
    rho_reject: float
    rho_apply: float
    min_fiducials: int
    pair_slop: float
    merge_radius: float
    outlier_distance: float
    max_stamp_age: float
    max_targets: int
    debounce_period: float
    rebuild_worker: str
    point_buffer: int
    input_reliability: str
    input_batch: int
    state_dir: str
    calibration_file: str
    calibration_name: str
    target_frames: tuple[str, ...]
    journal_fsync: bool
    stale_after: float
    status_period: float
    tf_broadcast: str
    point_mode: str
    sample_max_age: float
    sample_destination_source: str
    sample_tf_parent: str
    sample_tf_child: str
    marker_scale: float
    marker_arrow_gain: float
    max_markers: int
    max_candidates: int
    plan_within: float
    plan_min_gain_fraction: float
    plan_min_gain_length: float
    plan_max_fiducials: int

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> "Settings":
        """Build from ``{name: value}`` (missing names take their defaults).

        :raises ValueError: naming the first invalid value.
        """
        merged = {name: spec.default for name, spec in SPECS.items()}
        merged.update(values)
        error = validate(merged)
        if error:
            raise ValueError(error)
        for name, spec in SPECS.items():   # a ROS string array (a list; None when empty)
            if isinstance(spec.default, tuple):
                merged[name] = tuple(merged[name] or ())
        return cls(**{f.name: merged[f.name] for f in fields(cls)})

    @cached_property
    def state_files(self) -> Optional[StateDir]:
        """``state_dir`` resolved once, with the paths of its files
        (:class:`~.state_dir.StateDir`); None when ``state_dir`` is empty (nothing persists)."""
        return StateDir.resolve(self.state_dir) if self.state_dir else None

    def replace(self, **changes: Any) -> "Settings":
        """A copy with ``changes`` applied and validated.

        :raises ValueError: naming the first invalid value.
        """
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        values.update(changes)
        return Settings.from_mapping(values)


def validate_one(name: str, value: Any) -> Optional[str]:
    """Return why ``value`` is not valid for parameter ``name``, or ``None`` when it is."""
    spec = SPECS.get(name)
    if name in REMOVED:
        return f"parameter {name} no longer exists: {REMOVED[name]}"
    if spec is None:
        return f"unknown parameter {name!r}"
    kind = type(spec.default)
    if kind is tuple:
        return parse_target_frames(value)[1]
    if kind is bool:
        if not isinstance(value, bool):
            return f"{name} must be a bool, got {value!r}"
        return None
    if kind is str:
        if not isinstance(value, str):
            return f"{name} must be a string, got {value!r}"
        if spec.choices and value not in spec.choices:
            return f"{name} must be one of {', '.join(spec.choices)}; got {value!r}"
        frame = name.endswith("_frame") or (name.startswith("sample_tf_") and value != "")
        problem = frame_id_problem(value) if frame else None
        if problem:
            empty = " (or empty)" if name.startswith("sample_tf_") else ""
            return f"{name} is a tf frame id{empty}: it {problem}, got {quote(value)}"
        if name == "calibration_name" and value:
            problem = calibration_name_problem(value)
            return f"calibration_name: {problem}" if problem else None
        if name == "calibration_file" and is_calibration_name(value):
            problem = calibration_name_problem(value)
            return (f"calibration_file {quote(value)} is a calibration name (no '/', no .yaml): "
                    f"{problem}; or give the file's path" if problem else None)
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f"{name} must be a number, got {value!r}"
    if kind is int and not isinstance(value, int):
        return f"{name} must be an integer, got {value!r}"
    if not math.isfinite(value):
        return f"{name} must be finite, got {value!r}"
    low_ok = value > spec.low if spec.low_exclusive else value >= spec.low
    if not low_ok or value > spec.high:
        bracket = "(" if spec.low_exclusive else "["
        return f"{name} must be in {bracket}{spec.low:g}, {spec.high:g}], got {value!r}"
    return None


def validate(values: Mapping[str, Any]) -> Optional[str]:
    """Return why a full set of parameter values is not valid (each value, then the relations
    between them), or ``None`` when it is."""
    for name, value in values.items():
        error = validate_one(name, value)
        if error:
            return error

    def get(name: str) -> Any:
        return values.get(name, SPECS[name].default)

    same = same_frame_problem("destination_frame", get("destination_frame"),
                              get("working_frame"))
    if same:
        return f"working_frame {same}"
    problem = target_frames_problem(get("target_frames"), get("working_frame"),
                                    get("destination_frame"))
    if problem:
        return problem
    if is_calibration_name(get("calibration_file")) and not get("state_dir"):
        return (f"calibration_file {get('calibration_file')!r} is a calibration name (no '/', "
                f"no .yaml), read from state_dir/calibrations/, but state_dir is empty: give the "
                f"file's path")
    if get("sample_tf_parent") not in ("", get("destination_frame")):
        return (f"sample_tf_parent must be empty or destination_frame "
                f"{get('destination_frame')!r}, got {get('sample_tf_parent')!r}: a tf "
                f"sample's destination point is recorded in the destination frame (tf "
                f"looks sample_tf_child up there directly; the accumulator would reject "
                f"every sample in another frame)")
    if get("sample_tf_child"):
        parent = "sample_tf_parent" if get("sample_tf_parent") else \
            "sample_tf_parent (empty: destination_frame)"
        same = same_frame_problem(parent, get("destination_frame"),   # the parent (above)
                                  get("sample_tf_child"),
                                  "a tf sample's destination point is the origin of "
                                  "sample_tf_child in sample_tf_parent: in itself always 0")
        if same:
            return f"sample_tf_child {same}"
        if get("sample_tf_child") == get("working_frame"):
            return (f"sample_tf_child must not be working_frame {get('working_frame')!r}: a tf "
                    f"sample's destination point would be the working frame's origin, which is "
                    f"the registration itself (this node's /tf_static), not the measured point; "
                    f"name the frame carrying the target, e.g. the robot's tool frame")
    if values.get("sigma", 0.0) > 0 and values.get("sigma_axis", 0.0) > 0:
        return (f"give sigma or sigma_axis, not both (sigma {values['sigma']!r}, sigma_axis "
                f"{values['sigma_axis']!r}; 0 = unknown)")
    return rho_thresholds_error(values.get("rho_reject", 0.0), values.get("rho_apply", math.inf))
