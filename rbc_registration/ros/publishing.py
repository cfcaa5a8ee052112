"""What ``registration_node`` publishes about its model (a mixin of
:class:`~rbc_registration.ros.node.RegistrationNode`): the corrected and uncorrected
transforms, ``/tf_static`` (with the named targets of ``target_frames``), the markers,
``~/status`` with its diagnostics, and the calibration snapshot. See msg_docs/README.md for the
topics and frames.
"""

from __future__ import annotations

from typing import Any, Mapping, Optional, Sequence

import numpy as np
from rbc_registration_interfaces.msg import RegistrationStatus

from ..pipeline.named import parse_target_frames
from ..pipeline.snapshot import snapshot_json
from ..pipeline.state import ModelState
from . import conversions as conv
from .markers import markers_msg
from .status import diagnostics_msg, health_of, status_msg
from .tf_static import target_transforms
from .parts import NodeParts


class PublishingMixin(NodeParts):
    """Publishing of a new model and of the status; the node provides the publishers
    (``_pub_transform``, ``_pub_transform_u``, ``_pub_markers``, ``_pub_status``,
    ``_pub_diagnostics``), ``_pub_lock``, ``_tf`` (:class:`~.tf_static.StaticTf`), ``_settings``,
    ``_state``, ``_generation``, ``_ingest``, ``_health``, ``_snapshots``, ``_snapshot_lock``,
    ``_write_snapshot`` and, from
    :class:`~.planning.PlanningMixin`, ``_plan_model`` and ``_expected_target_error``."""

    _target_frame_names: frozenset = frozenset()   # the target frames on /tf_static now
    get_clock: Any
    get_logger: Any
    get_name: Any
    context: Any

    def _serve_model(self, state: ModelState, disabled_points: Mapping[str, Sequence[float]],
                     generation: int) -> Optional[ModelState]:
        """Serve and publish a new model of ``generation`` (recompute thread), unless
        ``~/reset`` has bumped the generation since; returns the model served before it, or
        ``None`` when ``state`` was discarded.

        The markers are built first, without the publishing lock (the executor's status timer
        takes it too). Then, under one hold of the lock, the model is swapped in and its
        transforms, ``/tf_static`` and markers are published: a ``~/status`` whose
        ``last_recompute`` is this rebuild (the documented sign that a rebuild is done) is
        published after them, never before. Once the node's context is shut down (Ctrl-C or
        SIGTERM during the rebuild) nothing more is published or saved: ``None``."""
        s = self._settings
        now = self.get_clock().now().to_msg()
        markers = markers_msg(state, s, now, disabled_points)
        try:
            previous = self._swap_and_publish(state, markers, generation, now)
        except Exception:
            if self._shut_down():
                return None     # Ctrl-C or SIGTERM during the rebuild: nothing more to publish
            raise
        if previous is None:
            return None
        self._publish_status()
        self._plan_model(state)   # ~/status expected_target_error follows from its thread
        if s.state_dir:
            self._snapshots.submit((state, generation))   # serialised and written in its thread
        return previous

    def _shut_down(self) -> bool:
        """True once the node's context is shut down: rclpy's SIGINT / SIGTERM handler does it at
        once, while a rebuild may still run in the recompute thread (joined in destroy_node),
        and whatever that thread publishes then fails on the invalid context."""
        return not self.context.ok()

    def _swap_and_publish(self, state: ModelState, markers: Any, generation: int,
                          now: Any) -> Optional[ModelState]:
        """Under one hold of the publishing lock, swap ``state`` in and publish its transforms,
        ``/tf_static`` and markers; returns the model served before, or ``None`` when ``~/reset``
        came since."""
        s = self._settings
        with self._pub_lock:
            if generation != self._generation:
                return None     # reset meanwhile: neither served, published nor saved
            previous, self._state = self._state, state
            if state.model is not None:
                corrected = conv.registration_to_transform(
                    state.model.corrected, s.destination_frame, s.working_frame, now)
                uncorrected = conv.registration_to_transform(
                    state.model.uncorrected, s.destination_frame, s.working_frame, now)
                self._pub_transform.publish(corrected)
                self._pub_transform_u.publish(uncorrected)
                self._tf_transforms = {"corrected": corrected, "uncorrected": uncorrected}
                self._loaded = None  # the live model replaces a calibration_file
                self._publish_tf()
            elif self._loaded is None and self._tf_transforms:
                # the live model became invalid (e.g. fiducials disabled below min_fiducials):
                # /tf_static must not hold a registration the node refuses to serve
                self._tf_transforms = {}
                self._publish_tf()
            self._pub_markers.publish(markers)
        return previous

    def _on_snapshot_error(self, exc: BaseException) -> None:
        # e.g. disk full: the journal still holds every measurement
        self.get_logger().error(f"calibration snapshot not written: {exc}")

    def _publish_tf(self) -> None:
        """/tf_static (call with ``_pub_lock`` held), in one message: the registration
        ``tf_broadcast`` chooses of the latest model (nothing of this node's child frame without
        one or with ``none``), and the named targets of ``target_frames`` at their
        destinations (:meth:`_target_frames`)."""
        s = self._settings
        chosen = self._tf_transforms.get(s.tf_broadcast)
        targets = self._target_frames()
        published = self._target_frame_names
        self._target_frame_names = frozenset(t.child_frame_id for t in targets)
        remove = set(published) - self._target_frame_names
        if chosen is None:
            remove.add(s.working_frame)
        self._tf.replace(targets + ([chosen] if chosen is not None else []), remove)

    def _target_frames(self) -> list[Any]:
        """The ``/tf_static`` entries of ``target_frames``: each target's ``~/correct_target``
        destination by the live model, or before one by a loaded calibration's answers; none
        without either (or when the model refuses the targets: logged)."""
        s = self._settings
        frames, _ = parse_target_frames(s.target_frames)
        loaded = self._loaded
        model = self._state.model
        if model is None and loaded is not None:
            model = loaded.model
        if not frames or model is None:
            return []
        xyz = np.array([f.point for f in frames], dtype=np.float64)
        try:
            destination = model.correct(xyz[:, :s.dimension]).destination
        except ValueError as exc:
            self.get_logger().error(f"target_frames not published: {exc}")
            return []
        if s.dimension == 2:            # z passes through, as for any target
            destination = np.column_stack([destination, xyz[:, 2]])
        return target_transforms([f.name for f in frames], destination, s.destination_frame,
                                 self.get_clock().now().to_msg())

    def status(self, state: Optional[ModelState] = None) -> RegistrationStatus:
        """The ``RegistrationStatus`` now (what ``~/status`` publishes) of ``state`` (default:
        the one served)."""
        state = self._state if state is None else state
        msg = status_msg(state, self._settings, self._ingest.counters(),
                         self.get_clock().now().to_msg(), self._expected_target_error())
        loaded = self._loaded
        if loaded is not None and state.model is None:
            msg.message = "; ".join(filter(None, (loaded.describe(), msg.message)))
        return msg

    def _publish_status(self) -> None:
        """Publish ``~/status`` and ``/diagnostics`` of the model served now. The model is read
        under the publishing lock: a status never names a rebuild whose transforms are not yet
        published, and never an older one than a status before it."""
        with self._pub_lock:
            state = self._state
            status = self.status(state)
            loaded = self._loaded
            self._health.stale_after = self._settings.stale_after
            health = health_of(status, self._health, self._ingest.journal_error,
                               loaded.describe() if loaded is not None else "", state.warning,
                               self.get_clock().ros_time_is_active)
            try:
                self._pub_status.publish(status)
                self._pub_diagnostics.publish(diagnostics_msg(
                    status, self.get_fully_qualified_name(), status.header.stamp, health))
            except Exception:
                if not self._shut_down():   # shut down: the recompute or planning thread's
                    raise                   # last status has no one to go to

    def _save(self, item: tuple[ModelState, int]) -> str:
        """Write the snapshot of ``(state, generation)`` unless ``~/reset`` came since."""
        state, generation = item
        s = self._settings
        path = s.state_files.snapshot
        text = snapshot_json(state, s.working_frame, s.destination_frame, s.dimension)
        with self._snapshot_lock:
            if generation != self._generation:
                return ""
            self._write_snapshot(path, text)
        return path
