"""Input subscriptions of ``registration_node`` that take the messages already queued in one
executor wake-up.

rclpy's executors take one message per subscription per wake-up, and every wake-up rebuilds the
wait set over all of the node's entities in Python (about 20 here: 3 subscriptions, 15 services,
a timer): in a burst of ``FiducialPair`` messages that rebuild, not the node's callback, is most
of the time per message. So after the
message the executor hands over, the callback takes up to ``input_batch - 1`` further messages
already waiting on the same subscription, the way the executor takes them
(``take_message(msg_type, raw)``), and handles each exactly as if the executor had handed it
over: in order, each through the same guarded callback. Nothing waits for a message to arrive:
the first empty take ends the batch. A ready service or timer waits at most one batch.
"""

from __future__ import annotations

from typing import Any, Callable

from rclpy._rclpy_pybind11 import InvalidHandle

from .guards import guard_input


def take_queued(subscription: Any, callback: Callable[[Any], None], limit: int) -> int:
    """Pass up to ``limit`` messages already queued on ``subscription`` (an rclpy
    ``Subscription``) to ``callback``, in arrival order; stop at the first empty take.

    :param limit: most messages to take (<= 0: none).
    :return: how many were taken.
    """
    taken = 0
    while taken < limit:
        try:
            with subscription.handle:
                got = subscription.handle.take_message(subscription.msg_type, subscription.raw)
        except InvalidHandle:   # destroyed meanwhile: nothing more to take
            break
        if got is None:
            break
        taken += 1
        callback(got[0])
    return taken


def batched_subscription(node: Any, msg_type: Any, topic: str, callback: Callable[[Any], None],
                         qos: Any, callback_group: Any, batch: Callable[[], int]) -> Any:
    """``node.create_subscription`` whose callback, after each message the executor hands it,
    takes up to ``batch() - 1`` more queued messages (:func:`take_queued`). ``callback`` is
    guarded per message (:func:`~rbc_registration.ros.guards.guard_input`): an unexpected error
    drops that message with a log line, and the batch goes on.

    :param batch: the current ``input_batch`` (most messages per wake-up, >= 1).
    :return: the subscription.
    """
    logger = node.get_logger()
    guarded = guard_input(logger, topic, callback)
    subscription = node.create_subscription(msg_type, topic, guarded, qos,
                                            callback_group=callback_group)

    def on_message(msg: Any) -> None:
        guarded(msg)
        take_queued(subscription, guarded, batch() - 1)

    subscription.callback = guard_input(logger, topic, on_message)
    return subscription
