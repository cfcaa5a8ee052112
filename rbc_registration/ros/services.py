"""The services of ``registration_node`` (a mixin of
:class:`~rbc_registration.ros.node.RegistrationNode`): target correction from one immutable
snapshot of the model, enabling fiducials, reset, recompute and save. Bad requests are answered
``success=False`` with the reason; see msg_docs/README.md.
"""

from __future__ import annotations

from typing import Any

from geometry_msgs.msg import PointStamped
from std_srvs.srv import Trigger

from rbc_registration_interfaces.srv import (CorrectTarget, CorrectTargets, GetFiducials,
                                             SetFiducialEnabled, TakeSample)

import re

from ..core.measurements.records import RejectedMeasurement
from ..core.rigid.scale import unit_mismatch
from ..pipeline.residuals import fiducial_residuals
from ..pipeline.state import EMPTY_STATE, session_mismatch
from . import conversions as conv
from . import samples, saved
from .markers import markers_msg
from .parts import NodeParts

#: ``~/recompute`` answers at once with this text; the rebuild covering the request is done when
#: ``~/status`` ``last_recompute`` is at or after the time it names (see
#: :func:`rebuild_requested_ns`).
REBUILD_REQUESTED = "rebuild requested at {sec}.{nsec:09d} s (node clock)"
_REQUESTED = re.compile(r"rebuild requested at (\d+)\.(\d{9}) s")


def rebuild_requested_ns(message: str) -> int:
    """The node-clock time [ns] named in a ``~/recompute`` answer.

    :raises ValueError: when ``message`` is not such an answer.
    """
    match = _REQUESTED.search(message)
    if match is None:
        raise ValueError(f"not a ~/recompute answer: {message!r}")
    return int(match.group(1)) * 10**9 + int(match.group(2))


class ServicesMixin(NodeParts):
    """Service callbacks; the node provides ``_state``, ``_settings``, ``_ingest``, ``_worker``,
    ``_pub_lock``, ``_generation``, ``_snapshot_lock``, ``_pub_markers``, ``_publish_status``
    and ``_snapshots`` (a :class:`~rbc_registration.pipeline.worker.LatestWriter` of
    ``(state, generation)``)."""


    def _correct(self, targets: list[PointStamped]) -> tuple[list[Any], str, str]:
        """Answer from one snapshot of the model (or, until there is one, of a loaded
        calibration file's answers): (results, "", note) or ([], reason, "")."""
        state, s, loaded = self._state, self._settings, self._loaded
        model: Any = state.model
        label = ""
        if model is None and loaded is not None:
            if loaded.model is None:
                return [], f"no model yet: {state.error}; {loaded.missing}", ""
            model = loaded.model
            label = model.decision.method + saved.FROM_FILE
        if model is None:
            return [], f"no model yet: {state.error}", ""
        moved = "" if label else session_mismatch(state, self._ingest.current_session())
        if moved:
            return [], moved, ""
        try:
            points, z = conv.targets_to_array(targets, s.working_frame, s.dimension)
            tc = model.correct(points)
        except ValueError as exc:
            return [], str(exc), ""
        decision = model.decision
        note = loaded.note() if label else (
            f"{decision.method}: corrections {'applied' if decision.apply else 'not applied'}"
            f" (decision {decision.mode.value}); {decision.reason}")
        mismatch = None if tc.inside_hull.any() else unit_mismatch(model.working, points,
                                                                     tc.inside_hull)
        if mismatch:                    # cheap: only when no target is inside the hull
            note += f"; warning: {mismatch}"
            self.get_logger().warning(mismatch, throttle_duration_sec=10.0)
        return conv.target_corrections_to_msgs(tc, z, decision.method, s.destination_frame,
                                               [t.header.stamp for t in targets],
                                               label), "", note

    def _on_correct_target(self, request: CorrectTarget.Request,
                           response: CorrectTarget.Response) -> CorrectTarget.Response:
        results, error, note = self._correct([request.target])
        if error:
            response.success, response.message = False, error
            return response
        conv.fill_correct_target_response(response, results[0])
        response.message = note
        return response

    def _on_correct_targets(self, request: CorrectTargets.Request,
                            response: CorrectTargets.Response) -> CorrectTargets.Response:
        if not request.targets:
            response.success, response.message = True, "no targets"
            return response
        if len(request.targets) > self._settings.max_targets:
            response.success = False
            response.message = (f"{len(request.targets)} targets in one request, more than "
                                f"max_targets ({self._settings.max_targets}): split the request")
            return response
        results, error, note = self._correct(list(request.targets))
        response.success, response.results, response.message = not error, results, error or note
        return response

    def _on_get_fiducials(self, request: GetFiducials.Request,
                          response: GetFiducials.Response) -> GetFiducials.Response:
        state = self._state
        method, rows = fiducial_residuals(state.model, self._ingest.fiducial_summaries())
        response.fiducials = [conv.fiducial_residual_msg(r) for r in rows]
        response.method = method
        response.success = state.model is not None
        response.message = (f"{len(rows)} fiducials; cv_error of {method}" if method
                            else f"no model yet: {state.error}")
        return response

    def _on_set_fiducial_enabled(self, request: SetFiducialEnabled.Request,
                                 response: SetFiducialEnabled.Response) -> Any:
        response.success, response.message = self._ingest.set_enabled(request.fiducial_id,
                                                                       request.enabled)
        if response.success:
            self._worker.notify()
        return response

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        with self._snapshot_lock:      # no snapshot of the old generation after the archive
            response.success, response.message = self._ingest.reset()
            if not response.success:   # the journal could not be archived: nothing forgotten
                return response
            with self._pub_lock:
                self._generation += 1  # a rebuild under way is neither served nor published
                self._state = EMPTY_STATE
                self._tf_transforms = {}
                self._loaded = None  # a calibration_file is forgotten too
                self._publish_tf()  # /tf_static without this node's child frame
        self._publish_status()
        with self._pub_lock:
            self._pub_markers.publish(markers_msg(EMPTY_STATE, self._settings,
                                                  self.get_clock().now().to_msg()))
        return response

    def _on_recompute(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        # Answered at once: the rebuild runs in the recompute thread, and services keep
        # answering from the current model meanwhile. Done when ~/status last_recompute is at or
        # after the request time (the rebuild covering it starts after the request).
        now = self.get_clock().now().nanoseconds
        self._worker.request_now()
        state = self._state
        current = (f"{len(state.fiducials.ids)} fiducials" if state.model is not None
                   else f"no model ({state.error})")
        response.success = True
        response.message = (REBUILD_REQUESTED.format(sec=now // 10**9, nsec=now % 10**9)
                            + f"; done when ~/status last_recompute is at or after that; until "
                              f"then answers come from the current model: {current}")
        return response

    def _on_save(self, request: Trigger.Request, response: Trigger.Response) -> Any:
        if not self._settings.state_dir:
            response.success, response.message = False, "state_dir is not set: nothing to save to"
            return response
        state = self._state
        snapshot = self._settings.state_files.snapshot
        previous = self._snapshots.last_error
        self._snapshots.submit((state, self._generation))   # written in the snapshot thread
        note = f"snapshot queued as {snapshot}" + (
            f" (the previous snapshot write failed: {previous})" if previous else "")
        try:
            path, command = saved.save(state, self._settings)
        except ValueError as exc:  # no model: the snapshot is written, no calibration
            response.success, response.message = False, f"{exc}; {note}"
            return response
        except OSError as exc:
            response.success, response.message = False, f"save failed: {exc}; {note}"
            return response
        response.success = not previous
        response.message = f"saved {path} ({note}); {command}"
        return response

    def _on_take_sample(self, request: TakeSample.Request,
                        response: TakeSample.Response) -> TakeSample.Response:
        try:
            args, error, taken = self._samples.pair(request.fiducial_id, self._settings)
        except RejectedMeasurement as exc:      # a point's stamp is not a time: counted once
            if self._settings.point_mode != "pair":     # pair: its topic callback counted it
                self._ingest.reject(exc)
            args, error, taken = None, f"rejected ({exc.reason}): {exc.message}", None
        record = None
        if args is not None:
            record, error = self._ingest.take(args._replace(group=request.group))
        if record is None:
            response.success, response.message = False, f"no sample taken: {error}"
            return response
        self._samples.mark_sampled(taken)   # no second sample of the same measurement
        if self._settings.point_mode == "pair":   # never rejected, nor recorded again, by pairing
            self._ingest.sampled(args.working_xyz, args.stamp_s, args.destination_xyz,
                                 taken.destination_stamp_s)
        self._measurements_changed()
        response.pair = samples.pair_message(record, args, self._settings)
        response.success = True
        response.message = (f"recorded fiducial {record.fiducial_id!r}"
                            f"{' (id by proximity)' if record.auto_id else ''}; the model is "
                            f"rebuilt after debounce")
        return response
