"""Callback boundaries of ``registration_node``: an unexpected exception in a callback is logged
and answered (services: ``success=False`` with the message), and never stops the node. Expected
errors (bad input) are handled inside the callbacks with their own reasons."""

from __future__ import annotations

from typing import Any, Callable


def guard_service(logger: Any, name: str,
                  callback: Callable[[Any, Any], Any]) -> Callable[[Any, Any], Any]:
    """Wrap a service callback whose response has ``success`` and ``message`` fields."""
    def guarded(request: Any, response: Any) -> Any:
        try:
            return callback(request, response)
        except Exception as exc:  # noqa: BLE001 - boundary
            logger.error(f"{name} failed: {type(exc).__name__}: {exc}")
            response.success, response.message = False, f"internal error: {exc}"
            return response
    return guarded


def guard_input(logger: Any, topic: str, callback: Callable[[Any], None]) -> Callable[[Any], None]:
    """Wrap a subscription callback: an unexpected error drops that message with a log line."""
    def guarded(msg: Any) -> None:
        try:
            callback(msg)
        except Exception as exc:  # noqa: BLE001 - boundary
            logger.error(f"{topic}: message dropped: {type(exc).__name__}: {exc}")
    return guarded
