"""``registration_node``: live registration of a working frame (tracker) to a destination frame
(robot / world) from fiducial pairs, improved by restoring the rigid-body condition.

Callbacks convert messages to numpy, call :mod:`rbc_registration.core`, convert back and
publish. The served model is an immutable :class:`~rbc_registration.pipeline.state.ModelState`
swapped atomically by the recompute thread (:mod:`rbc_registration.pipeline.worker`), so services
never wait for a recompute. See msg_docs/README.md for every topic, service, parameter and frame.
"""

from __future__ import annotations

import re
import sys
import threading
import time
from typing import Any, Callable, Optional

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PointStamped, TransformStamped
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.logging import get_logger
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from rbc_registration_interfaces.msg import FiducialPair, RegistrationStatus
from rbc_registration_interfaces.srv import (CorrectTarget, CorrectTargets, GetFiducials,
                                             SetFiducialEnabled, SuggestNext, TakeSample)

from ..core.measurements.accumulator import FiducialAccumulator
from ..core.measurements.pairing import DESTINATION, WORKING, StampPairer
from ..core.measurements.records import RejectedMeasurement, quote
from ..pipeline.files import StateDirLock
from ..pipeline.health import HealthMonitor
from ..pipeline.ingest import Ingest
from ..pipeline.journal import Journal
from ..pipeline.snapshot import start_warnings, write_atomic
from ..pipeline.build_process import BuildCancelled, ProcessBuilder
from ..pipeline.state import (BUILDING_STATE, EMPTY_STATE, ModelState, first_build_failed,
                               warm_start, with_warning)
from ..pipeline.worker import LatestWriter, RecomputeWorker
from ..runtime import freeze_startup_objects
from . import conversions as conv
from . import params, samples, saved
from .batching import batched_subscription
from .guards import guard_service
from .lanes import LaneExecutor
from .outputs import output_events
from .param_callbacks import ParametersMixin
from .planning import PlanningMixin
from .publishing import PublishingMixin
from .services import ServicesMixin
from .tf_static import StaticTf

LATCHED = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Measurements are precious: KEEP_ALL + RELIABLE, so a burst faster than the node makes the
# publisher wait instead of samples being overwritten (`input_reliability` best_effort: depth 1000).
INPUT = {"reliable": QoSProfile(depth=1000, history=HistoryPolicy.KEEP_ALL,
                                reliability=ReliabilityPolicy.RELIABLE),
         "best_effort": QoSProfile(depth=1000, history=HistoryPolicy.KEEP_LAST,
                                   reliability=ReliabilityPolicy.BEST_EFFORT)}


#: The node's name unless remapped (``-r __node:=NAME``).
NODE_NAME = "registration_node"


class RegistrationNode(ServicesMixin, PublishingMixin, ParametersMixin, PlanningMixin, Node):
    """The registration node (see the module docstring and msg_docs/README.md).

    :param build: builds the :class:`ModelState` from the fiducials, settings and a stamp
        (default: a :class:`~rbc_registration.pipeline.build_process.ProcessBuilder`, which runs
        :func:`~rbc_registration.pipeline.state.build_state` in the recompute thread or a child
        process as ``rebuild_worker`` says).
    :param write_snapshot: writes the calibration snapshot ``(path, text)`` (default
        :func:`~rbc_registration.pipeline.snapshot.write_atomic`).
    :param clock: monotonic seconds for the recompute debounce (default
        :func:`time.monotonic`).
    :param kwargs: passed to ``rclpy.node.Node`` (``context``, ``parameter_overrides``, ...).
    :raises ValueError: when a parameter's starting value is invalid, another node holds
        ``state_dir`` (:class:`~rbc_registration.pipeline.files.StateDirBusy`), the journal is
        not a regular file or was written with other frames / another dimension.
    :raises OSError: when ``state_dir`` cannot be created or its journal opened.

    A node that fails half way is destroyed again (lock released, threads stopped).
    """

    def __init__(self, node_name: str = NODE_NAME, *,
                 build: Optional[Callable[..., ModelState]] = None,
                 write_snapshot: Callable[[str, str], None] = write_atomic,
                 clock: Callable[[], float] = time.monotonic, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        try:
            self._start(build, write_snapshot, clock)
        except BaseException:
            self.destroy_node()
            raise

    def _start(self, build: Optional[Callable[..., ModelState]],
               write_snapshot: Callable[[str, str], None], clock: Callable[[], float]) -> None:
        """The node's start, in order: parameters (and a calibration file), shared state, the
        journal and what it restores, the outputs, the inputs and services, what a loaded
        calibration publishes, then the threads."""
        self._declare()
        # The default builder's child process (rebuild_worker) is killed in destroy_node.
        self._builder = (ProcessBuilder(warn=self.get_logger().warning) if build is None
                         else None)
        self._build = build if build is not None else self._builder
        self._write_snapshot = write_snapshot
        self._pub_lock = threading.Lock()
        # ~/reset against the snapshot thread: a snapshot is written only while its generation
        # is current, and the reset archives the files and bumps the generation under it.
        self._snapshot_lock = threading.Lock()
        self._health = HealthMonitor(self._settings.stale_after)  # /diagnostics (pipeline.health)
        self._state: ModelState = EMPTY_STATE
        self._generation = 0  # bumped by ~/reset: a rebuild of an older generation is dropped
        # The transforms /tf_static chooses from ({tf_broadcast: TransformStamped}); {} = none.
        self._tf_transforms: dict[str, TransformStamped] = {}
        restored = self._open_journal()
        self._create_outputs()
        self._create_inputs_and_services()
        self.add_parameter_callbacks()
        if self._loaded is not None:
            self._publish_loaded()
        self._start_threads(restored, clock)

    def _declare(self) -> None:
        """Parameters (refused, naming why, before anything starts) and a calibration file."""
        self._settings = params.declare(self)
        unknown = params.unknown_overrides(getattr(self, "_parameter_overrides", {}))
        if unknown:
            self.get_logger().warning(unknown)
        s = self._settings
        # A calibration_file is read (and refused, naming why) before anything else starts.
        self._loaded = saved.load(s.calibration_file, s) if s.calibration_file else None
        if samples.source_error(s.sample_destination_source):
            raise ValueError(samples.source_error(s.sample_destination_source))
        self._samples = samples.SampleTaker(self)

    def _open_journal(self) -> int:
        """The accumulator, the writer's lock, the journal and the ingestion; returns the
        measurements restored (from the checkpoint and the journal)."""
        s = self._settings
        accumulator = FiducialAccumulator(s.dimension, s.working_frame, s.destination_frame,
                                          s.merge_radius, s.outlier_distance, s.max_stamp_age)
        journal = None
        if s.state_dir:
            # One writer per state_dir, for the node's life: taken before anything is touched.
            self._state_lock = StateDirLock(s.state_dir)
            for warning in start_warnings(s.state_dir, s):
                self.get_logger().warning(warning)
            journal = Journal(s.state_dir, {"working_frame": s.working_frame,
                                            "destination_frame": s.destination_frame,
                                            "dimension": s.dimension}, fsync=s.journal_fsync)
        self._ingest = Ingest(accumulator, StampPairer(s.pair_slop, s.point_buffer), journal,
                              self.get_logger(), lambda: self.get_clock().now().nanoseconds * 1e-9,
                              hold_s=s.sample_max_age if s.point_mode == "pair" else 0.0)
        return self._ingest.restore()

    def _create_outputs(self) -> None:
        """/tf_static and the publishers (latched where a late subscriber needs the last)."""
        self._tf = StaticTf(self)
        if not self._tf.available:
            self.get_logger().warning(f"static tf off: {self._tf.missing}; /tf_static is not "
                                      "published (~/transform still is)")
        def publisher(msg_type: Any, topic: str, qos: Any) -> Any:
            return self.create_publisher(msg_type, topic, qos, event_callbacks=output_events())

        self._pub_transform = publisher(TransformStamped, "~/transform", LATCHED)
        self._pub_transform_u = publisher(TransformStamped, "~/transform_uncorrected", LATCHED)
        self._pub_status = publisher(RegistrationStatus, "~/status", LATCHED)
        self._pub_markers = publisher(MarkerArray, "~/markers", LATCHED)
        self._pub_diagnostics = publisher(DiagnosticArray, "/diagnostics", 10)

    def _create_inputs_and_services(self) -> None:
        """The input subscriptions, the services (each correction service in a lane of its
        own) and the status timer."""
        s = self._settings
        inputs, qos = MutuallyExclusiveCallbackGroup(), INPUT[s.input_reliability]
        for msg_type, topic, callback in (
                (FiducialPair, "~/fiducial_pairs", self._on_fiducial_pair),
                (PointStamped, "~/working_point", self._on_working_point),
                (PointStamped, "~/destination_point", self._on_destination_point)):
            # Up to input_batch queued messages per executor wake-up (ros/batching.py).
            batched_subscription(self, msg_type, topic, callback, qos, inputs,
                                 lambda: self._settings.input_batch)
        services = ReentrantCallbackGroup()
        # Each correction service in a group of its own, run by main()'s executor in a thread
        # of its own (ros/lanes.py): a large ~/correct_targets request, taken and answered in
        # its lane, never holds up another client's ~/correct_target.
        one, many = MutuallyExclusiveCallbackGroup(), MutuallyExclusiveCallbackGroup()
        #: The callback groups that get a thread of their own ({group: thread name}).
        self.lanes = {one: "correct_target", many: "correct_targets"}
        for srv_type, name, callback, group in (
                (CorrectTarget, "~/correct_target", self._on_correct_target, one),
                (CorrectTargets, "~/correct_targets", self._on_correct_targets, many),
                (SetFiducialEnabled, "~/set_fiducial_enabled", self._on_set_fiducial_enabled, None),
                (GetFiducials, "~/get_fiducials", self._on_get_fiducials, None),
                (Trigger, "~/reset", self._on_reset, None),
                (Trigger, "~/recompute", self._on_recompute, None),
                (Trigger, "~/save", self._on_save, None),
                (TakeSample, "~/take_sample", self._on_take_sample, None),
                (SuggestNext, "~/suggest_next", self._on_suggest_next, None)):
            self.create_service(srv_type, name, guard_service(self.get_logger(), name, callback),
                                callback_group=services if group is None else group)
        # On the steady clock: with use_sim_time a paused or absent /clock would stop the
        # heartbeat of ~/status and /diagnostics (their stamps stay on the node clock).
        self.create_timer(s.status_period, self._publish_status,
                          callback_group=MutuallyExclusiveCallbackGroup(),
                          clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _publish_loaded(self) -> None:
        """What a loaded calibration file publishes until a live model replaces it."""
        transform = saved.calibration_transform(self._loaded.calibration,
                                                self.get_clock().now().to_msg())
        # on the topic of the file's registration, so each topic keeps its meaning when the
        # live model replaces the file; /tf_static holds it whichever tf_broadcast chooses
        uncorrected = self._loaded.calibration.registration == "uncorrected"
        with self._pub_lock:
            (self._pub_transform_u if uncorrected else self._pub_transform).publish(transform)
            self._tf_transforms = dict.fromkeys(("corrected", "uncorrected"), transform)
            self._publish_tf()
        self.get_logger().info(self._loaded.describe())

    def _start_threads(self, restored: int, clock: Callable[[], float]) -> None:
        """The snapshot writer, the planner and the recompute threads; a first rebuild of what
        was restored; the first status and the start's log line."""
        s = self._settings
        self._snapshots = LatestWriter(self._save_and_checkpoint, self._on_snapshot_error)
        self._start_planner()   # the planner's error model of every new model, in its thread
        self._worker = RecomputeWorker(self._rebuild, lambda: self._settings.debounce_period,
                                       self._on_worker_error, clock)
        how = f" ({self._ingest.restore_summary})" if self._ingest.restore_summary else ""
        # logged before the first rebuild and status: a model built from what was restored is
        # never served before the line that says what was restored
        self.get_logger().info(
            f"registering {s.working_frame!r} -> {s.destination_frame!r} ({s.dimension}D); "
            f"state_dir {s.state_dir or '(none: no persistence)'}; restored {restored} "
            f"measurements{how}; /tf_static {s.tf_broadcast if self._tf.available else 'off'}")
        if restored:
            self._state = BUILDING_STATE
            self._worker.request_now()
        self._publish_status()

    # -- inputs -------------------------------------------------------------------------------
    def _on_fiducial_pair(self, msg: FiducialPair) -> None:
        try:
            args = conv.fiducial_pair_to_args(msg)
        except RejectedMeasurement as exc:      # its stamp is not a time
            self._ingest.reject(RejectedMeasurement(
                exc.reason, f"FiducialPair {quote(msg.fiducial_id)}: {exc.message}"))
            return
        if self._ingest.measurement(args):
            self._measurements_changed()

    def _on_point(self, stream: str, msg: PointStamped) -> None:
        self._samples.update(stream, msg)  # the latest point, for ~/take_sample
        if self._settings.point_mode != "pair":
            return
        try:
            point = conv.point_stamped_to_tuple(msg)
        except RejectedMeasurement as exc:      # its stamp is not a time
            self._ingest.reject(RejectedMeasurement(exc.reason, f"{stream} point: {exc.message}"))
            return
        recorded: list = []    # accepted, or a duplicate of a recorded measurement
        pairs = self._ingest.point(stream, *point, recorded=recorded)
        if recorded:
            self._samples.mark_paired(recorded)
        if pairs:
            self._measurements_changed()

    def _measurements_changed(self) -> None:
        """A measurement was accepted: the recompute thread is woken, and until a first model
        exists the state served says it is being built (not "no measurements yet")."""
        if self._state is EMPTY_STATE:
            with self._pub_lock:
                if self._state is EMPTY_STATE:
                    self._state = BUILDING_STATE
        self._worker.notify()

    def _on_working_point(self, msg: PointStamped) -> None:
        self._on_point(WORKING, msg)

    def _on_destination_point(self, msg: PointStamped) -> None:
        self._on_point(DESTINATION, msg)

    # -- model --------------------------------------------------------------------------------
    @property
    def state(self) -> ModelState:
        """The model state currently served (immutable)."""
        return self._state

    def _rebuild(self) -> None:
        generation = self._generation
        fiducials = self._ingest.fiducial_set()
        disabled_points = self._ingest.disabled_points()
        settings = self._settings
        # kriging_warm_start: the served model's kriging hyper-parameters start the next fit.
        state = self._build(fiducials, settings, self.get_clock().now().nanoseconds,
                            warm_start(self._state) if settings.kriging_warm_start else None)
        state = with_warning(state, self._ingest.dropped_z_warning())
        previous = self._serve_model(state, disabled_points, generation)
        if previous is None:
            return              # ~/reset came meanwhile
        if state.error:
            self.get_logger().warning(state.error)
        elif state.warning and _wording(state.warning) != _wording(previous.warning):
            self.get_logger().warning(state.warning)

    def _save_and_checkpoint(self, item: tuple[ModelState, int]) -> str:
        """The snapshot of ``(state, generation)`` (:meth:`_save`), then the checkpoint of the
        measurements now (pipeline/checkpoint.py: a restart loads it and replays only the
        journal's tail), both unless ``~/reset`` came since; in the snapshot thread."""
        path = self._save(item)
        if path:
            text = self._ingest.checkpoint_text()
            with self._snapshot_lock:
                if text and item[1] == self._generation:
                    write_atomic(self._settings.state_files.checkpoint, text)
        return path

    def _on_worker_error(self, exc: BaseException) -> None:
        if isinstance(exc, BuildCancelled):   # destroy_node killed the build process
            return
        self.get_logger().error(f"recompute failed: {type(exc).__name__}: {exc}")
        with self._pub_lock:     # no model to keep: the answers say why there is none
            if self._state is BUILDING_STATE:
                self._state = first_build_failed(f"{type(exc).__name__}: {exc}")
        self._publish_status()

    def destroy_node(self) -> None:
        """Stop the recompute, planning and snapshot threads, close the journal, release
        ``state_dir``, then destroy the node (also of a node whose start failed half way)."""
        # The build process first: a rebuild running in it ends at once, so the recompute
        # thread's join does not wait for it (one in the thread still finishes first).
        for name, stop in (("_builder", "close"), ("_worker", "stop"), ("_planner", "cancel"),
                           ("_snapshots", "stop"), ("_ingest", "close"),
                           ("_state_lock", "release")):
            part = self.__dict__.pop(name, None)
            if part is not None:
                getattr(part, stop)()
        super().destroy_node()


def _wording(warning: str) -> str:
    """A model-state warning without its numbers (ids kept: quoted, or digits within a word such
    as H012): the node logs a warning again only when this changes, not at every rebuild whose
    numbers moved (the status carries the current ones)."""
    return re.sub(r"('[^']*'|\"[^\"]*\")|(?<![\w.])\d+(\.\d*)?(e[-+]?\d+)?(?![\w.])",
                  lambda m: m.group(1) or "#", warning)


def start_failure(exc: BaseException) -> str:
    """The one FATAL line for a start-up failure (line breaks of the reason escaped)."""
    text = str(exc) if not isinstance(exc, OSError) or exc.filename is None else (
        f"{exc.filename}: {exc.strerror or exc}")
    return "cannot start: " + text.replace("\r", "\\r").replace("\n", "\\n")


def startup_logger_name(args: Optional[list[str]] = None) -> str:
    """The logger name of the node as the command line remaps it (``-r __node:=NAME`` or
    ``__name:=NAME``, ``-r __ns:=/ns``, also as ``registration_node:__node:=NAME``; as in rcl,
    the first rule of each wins), for the lines logged before the node exists or after it
    failed: with several nodes in a launch, the FATAL line names the one that could not start.
    rclpy's node loggers join the namespace and name with dots."""
    argv = sys.argv if args is None else args
    name, namespace = None, None
    ros = False                             # within --ros-args ... [--]: rcl reads only those
    for flag, rule in zip(argv, argv[1:]):
        if flag in ("--ros-args", "--"):
            ros = flag == "--ros-args"
        if not ros or flag not in ("-r", "--remap"):
            continue
        target, sep, value = rule.partition(":=")
        node, _, key = target.rpartition(":")
        if not sep or (node and node != NODE_NAME) or not value:
            continue
        if key in ("__node", "__name") and name is None:    # rcl: both spellings, first wins
            name = value
        elif key == "__ns" and namespace is None:
            namespace = value
    return ".".join(part for part in (*(namespace or "").split("/"), name or NODE_NAME) if part)


def main(args: Optional[list[str]] = None, **node_options: Any) -> None:
    """Console script ``registration_node``: spin the node on a :class:`~.lanes.LaneExecutor`
    (single-threaded; ``~/correct_target`` and ``~/correct_targets`` each in a thread of its own).

    :param node_options: passed to :class:`RegistrationNode` (e.g. ``write_snapshot``).

    A SIGINT or SIGTERM while the node starts stops it with status 0 and one INFO line
    ``stopped while starting (shutdown requested)``; one while it spins stops it with status 0
    and no line, also when the signal lands inside the executor's wait (its failure on the
    shut-down context is logged at DEBUG).

    Exits with status 1 and one FATAL line ``cannot start: <path and reason>`` when a
    parameter is invalid, ``state_dir`` is in use by another node, is not a usable directory,
    or holds a journal that is not a regular file or belongs to another setup, or a
    ``calibration_file`` does not validate; any other error before the node spins is one line
    too, ``cannot start: <exception type>: <message>``.
    """
    logger = get_logger(startup_logger_name(args))
    try:
        rclpy.init(args=args)
    except RuntimeError as exc:  # rcl's error, e.g. a malformed --ros-args rule: one line
        hint = (" (an empty value is written -p name:=\"''\")"
                if "parameter override rule" in str(exc) else "")
        logger.fatal(f"cannot start: {exc}{hint}")
        raise SystemExit(1) from None
    node: Optional[RegistrationNode] = None
    executor: Optional[LaneExecutor] = None
    code, spinning = 0, False
    try:
        # Single-threaded but for the correction services' lanes (ros/lanes.py): in rclpy it
        # takes messages about twice as fast as the multi-threaded executor; model rebuilds run
        # in their own thread, so services still answer meanwhile. Made before the node: a
        # SIGTERM while the node is being made then stops it cleanly.
        executor = LaneExecutor()
        node = RegistrationNode(**node_options)
        executor.add_node(node)
        for group, name in node.lanes.items():
            executor.add_lane(group, name)
        freeze_startup_objects()    # shorter full garbage collections (runtime.py)
        spinning = True
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception as exc:
        if not rclpy.ok():
            # SIGINT/SIGTERM: rclpy's handler shut the context down, and whatever was being
            # created (while starting) or the executor's next wait set (while spinning: the
            # signal came between spin's context check and spin_once) failed on it. A
            # requested stop, not a failure.
            if spinning:
                logger.debug(
                    f"stopped (shutdown requested): {type(exc).__name__}: {exc}")
            else:
                logger.info(
                    "stopped while starting (shutdown requested)")
        elif isinstance(exc, (ValueError, ParameterException, OSError)):
            logger.fatal(start_failure(exc))
            code = 1
        elif node is not None:
            raise             # a failure while spinning keeps its traceback
        else:                 # any other error while starting (e.g. reading a calibration_file)
            reason = start_failure(exc).removeprefix("cannot start: ")
            logger.fatal(f"cannot start: {type(exc).__name__}: "
                                                  f"{reason}")
            code = 1
    finally:
        if executor is not None:
            executor.shutdown()       # the lane threads joined before the node goes
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    if code:
        raise SystemExit(code)


if __name__ == "__main__":
    main()
