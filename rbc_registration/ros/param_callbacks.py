"""The parameter callbacks of ``registration_node`` (a mixin of
:class:`~rbc_registration.ros.node.RegistrationNode`): rclpy's reasons for a wrong type or an
undeclared parameter made to name what was wrong; validation of a change (refused with the
reason, nothing applied); an accepted change applied to the ingestion, tf and the next rebuild.
"""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.parameter import Parameter

from ..pipeline.settings import SPECS
from . import params, samples


class ParametersMixin:
    """Parameter callbacks; the node provides ``_settings``, ``_ingest``, ``_pub_lock``,
    ``_publish_tf`` and ``_worker``."""

    _settings: Any
    _ingest: Any
    _pub_lock: Any
    _worker: Any
    _publish_tf: Any

    def _apply_descriptor(self, parameter: Parameter, descriptor: Any = None,
                          *args: Any, **kwargs: Any) -> Any:
        """rclpy's type check, with a reason naming the parameter and the types (rclpy 3.11+
        prints the type codes only: "expected '3' got '2'"), for rclpy's own parameters
        (``use_sim_time``) too."""
        result = super()._apply_descriptor(parameter, descriptor, *args, **kwargs)
        if not result.successful and result.reason.startswith("Wrong parameter type"):
            if descriptor is None:
                descriptor = self.describe_parameter(parameter.name)
            result.reason = params.type_error(parameter.name, parameter.type_.name,
                                              parameter.value,
                                              Parameter.Type(descriptor.type).name)
        return result

    def _check_undeclared_parameters(self, parameter_list: list[Parameter]) -> None:
        """rclpy's check, naming the unknown parameters (rclpy lists none: "[]")."""
        unknown = [p.name for p in parameter_list if not self.has_parameter(p.name)]
        if unknown and not getattr(self, "_allow_undeclared_parameters", False):
            raise ParameterNotDeclaredException(unknown)
        super()._check_undeclared_parameters(parameter_list)

    def _on_set_parameters(self, parameters: list[Parameter]) -> Any:
        changes = {p.name: p.value for p in parameters if p.name in SPECS}
        error = samples.source_error(changes.get("sample_destination_source", ""))
        if error:
            return SetParametersResult(successful=False, reason=error)
        try:
            self._settings.replace(**changes)
        except ValueError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _on_parameters_set(self, parameters: list[Parameter]) -> None:
        changes = {p.name: p.value for p in parameters if p.name in SPECS}
        if not changes:
            return
        self._settings = self._settings.replace(**changes)
        self._ingest.configure(self._settings)
        if "tf_broadcast" in changes:
            with self._pub_lock:
                self._publish_tf()
        self.get_logger().info(f"parameters changed: {changes}")
        self._worker.notify()
        self._worker.wake()   # a pending batch is due by the new debounce_period
