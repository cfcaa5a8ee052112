"""The parameter callbacks of ``registration_node`` (a mixin of
:class:`~rbc_registration.ros.node.RegistrationNode`), on rclpy's public callbacks only:

- pre-set (:meth:`ParametersMixin._pre_set_parameters`): an undeclared parameter is refused
  naming it, and a value of the wrong ROS type is marked with the reason naming the parameter
  and both types (rclpy's own reason gives type codes only);
- on-set (:meth:`ParametersMixin._on_set_parameters`): a marked value, or a change the
  :class:`~rbc_registration.pipeline.settings.Settings` refuse, is refused with its reason and
  nothing is applied;
- post-set (:meth:`ParametersMixin._on_parameters_set`): an accepted change is applied to the
  ingestion, tf and the next rebuild.
"""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.parameter import Parameter

from ..pipeline.settings import SPECS
from . import params, samples
from .parts import NodeParts


class WrongTypeParameter(Parameter):
    """A set request's value of the wrong ROS type, held back by the pre-set callback: it carries
    the parameter's current value (so rclpy's descriptor checks pass it on unchanged) and the
    ``reason`` the on-set callback refuses the request with."""

    def __init__(self, current: Parameter, reason: str) -> None:
        super().__init__(current.name, current.type_, current.value)
        self.reason = reason


class ParametersMixin(NodeParts):
    """Parameter callbacks; the node provides ``_settings``, ``_ingest``, ``_pub_lock``,
    ``_publish_tf`` and ``_worker``, and registers the three callbacks with
    :meth:`add_parameter_callbacks`."""


    def add_parameter_callbacks(self: Any) -> None:
        """Register the pre-set, on-set and post-set callbacks (rclpy's public API)."""
        self.add_pre_set_parameters_callback(self._pre_set_parameters)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._on_parameters_set)

    def _pre_set_parameters(self: Any, parameters: list[Parameter]) -> list[Parameter]:
        """Refuse undeclared parameters by name (rclpy's own check lists none: "[]"); replace
        each value of the wrong type for its declared (not dynamically typed) descriptor by a
        :class:`WrongTypeParameter` naming the parameter and the types, for rclpy's own
        parameters (``use_sim_time``) too.

        :raises ParameterNotDeclaredException: naming the undeclared parameters (rclpy's
            parameter service answers it as the request's reason).
        """
        unknown = [p.name for p in parameters if not self.has_parameter(p.name)]
        if unknown:
            raise ParameterNotDeclaredException(unknown)
        checked = []
        for parameter in parameters:
            descriptor = self.describe_parameter(parameter.name)
            if (not descriptor.dynamic_typing and parameter.type_ != Parameter.Type.NOT_SET
                    and parameter.type_.value != descriptor.type):
                reason = params.type_error(parameter.name, parameter.type_.name, parameter.value,
                                           Parameter.Type(descriptor.type).name)
                parameter = WrongTypeParameter(self.get_parameter(parameter.name), reason)
            checked.append(parameter)
        return checked

    def _on_set_parameters(self, parameters: list[Parameter]) -> Any:
        """Refuse a change with its reason (a wrong type marked by the pre-set callback, a
        sample source or settings the change makes invalid); nothing is applied then."""
        for parameter in parameters:
            if isinstance(parameter, WrongTypeParameter):
                return SetParametersResult(successful=False, reason=parameter.reason)
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
        """Apply an accepted change: ingestion, tf broadcast and the next rebuild."""
        changes = {p.name: p.value for p in parameters if p.name in SPECS}
        if not changes:
            return
        self._settings = self._settings.replace(**changes)
        self._ingest.configure(self._settings)
        if "tf_broadcast" in changes or "target_frames" in changes:
            with self._pub_lock:
                self._publish_tf()
        self.get_logger().info(f"parameters changed: {changes}")
        self._worker.notify()
        self._worker.wake()   # a pending batch is due by the new debounce_period
