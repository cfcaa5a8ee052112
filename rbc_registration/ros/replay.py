"""Replay a bag into the live ROS graph (rclpy): every message is published, as recorded
(serialized CDR, header stamps unchanged), at its receive time scaled by ``rate``.

Imported only by ``rbc-registration replay`` and the demo, so ``evaluate`` and ``synth-bag`` never
load rclpy. The whole bag is read into memory first.
"""

from __future__ import annotations

import importlib
import math
import time
from pathlib import Path
from typing import Any, NamedTuple, Optional, Sequence, Union

from ..io.bag.reader import read_raw
from ..io.bag.records import (DEFAULT_MAX_GAP, MAX_REPLAY_WAIT, REPLAY_RATES, BagError,
                              RawMessage, topic_name_error)
from ..io.escape import terminal
from ..io.progress import Progress

SETTLE_S = 0.5      # after the first subscriber matched: time for the others to be discovered
ACK_TIMEOUT_S = 10.0
#: Topics replayed transient-local (tf2's static transforms): the rest volatile.
LATCHED_TOPICS = frozenset({"/tf_static"})
#: How long a publish may wait for slow subscribers to take earlier messages [s]: a reliable,
#: keep-all publisher whose subscriber's history is full fails after the middleware's blocking
#: time; the message is published again once they acknowledged, and the replay stops with one
#: line only when nothing was taken for this long.
STALL_TIMEOUT_S = 30.0


class ReplayResult(NamedTuple):
    """What a replay did: messages published, distinct topics, wall time of publishing [s]
    (without the final wait for acknowledgements), passes."""

    published: int
    topics: int
    seconds: float
    passes: int


def message_class(msgtype: str) -> Any:
    """``pkg/msg/Type`` -> the rclpy message class.

    :raises BagError: when the package is not installed for Python.
    """
    pkg, _, name = msgtype.rpartition("/")
    module = pkg.replace("/", ".")
    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError):
        raise BagError(f"missing type definition: no Python message type {msgtype} (is the "
                       f"package {msgtype.split('/')[0]} installed?)") from None


def _wait_for_subscribers(publishers: dict[str, Any], wait: float,
                          log: Any) -> None:
    """Wait until a subscriber matched (then ``SETTLE_S`` more) or ``wait`` seconds passed."""
    if wait <= 0:
        return
    end = time.monotonic() + wait
    first = None
    while time.monotonic() < end:
        matched = [t for t, p in publishers.items() if p.get_subscription_count() > 0]
        if len(matched) == len(publishers):
            return
        if matched and first is None:
            first = time.monotonic()
        if first is not None and time.monotonic() - first >= SETTLE_S:
            break
        time.sleep(0.02)
    missing = [t for t, p in publishers.items() if p.get_subscription_count() == 0]
    if missing:
        log(f"replay: no subscriber on {terminal(', '.join(missing))} (after {wait:g} s at most); "
            "publishing anyway")


def replay(bag: Union[str, Path], rate: float = 1.0, loop: bool = False,
           topics: Optional[Sequence[str]] = None, wait: float = 5.0,
           context: Any = None, progress: bool = True, log: Any = print,
           max_gap: float = DEFAULT_MAX_GAP) -> ReplayResult:
    """Publish the messages of ``bag`` with their recorded timing divided by ``rate``.

    :param rate: time scale (> 0): 2 plays twice as fast.
    :param loop: play again and again until interrupted (KeyboardInterrupt).
    :param topics: only these topics (default: all whose type rclpy knows).
    :param wait: seconds to wait at most for subscribers before the first message.
    :param max_gap: longest pause between two messages [s of wall time, after ``rate``]; a
        longer gap in the receive times is shortened to it, with one line (:func:`schedule`).
    :param context: an initialised ``rclpy.Context`` to use; default: a new one, shut down after.
    :raises BagError: for a bad bag, an unknown topic or a type rclpy does not know.
    :raises ValueError: for a rate outside ``REPLAY_RATES`` or a wait outside
        [0, ``MAX_REPLAY_WAIT``] (NaN included).
    """
    low, high = REPLAY_RATES
    if not low <= rate <= high:
        raise ValueError(f"rate must be in [{low:g}, {high:g}], got {rate!r}")
    if not 0 <= wait <= MAX_REPLAY_WAIT:
        raise ValueError(f"wait must be in [0, {MAX_REPLAY_WAIT:g}] s, got {wait!r}")
    if not 0 <= max_gap <= MAX_REPLAY_WAIT:
        raise ValueError(f"max_gap must be in [0, {MAX_REPLAY_WAIT:g}] s, got {max_gap!r}")
    messages = read_raw(bag, topics, progress=progress,
                        warn=lambda line: log(f"replay: {terminal(line)}"))
    types = {m.topic: m.msgtype for m in messages}
    for topic in types:     # rclpy would raise its own exception (a traceback) on a bad name
        if topic_name_error(topic):
            raise BagError(f"bag {bag}: {topic_name_error(topic)}: it cannot be published "
                           "(--topics names the ones to replay)")
    classes, skipped = {}, []
    for topic, msgtype in types.items():
        try:
            classes[topic] = message_class(msgtype)
        except BagError:
            if topics:
                raise
            skipped.append(f"{topic} [{msgtype}]")
            log(f"replay: skipping {terminal(topic)}: no Python message type {terminal(msgtype)}")
    messages = [m for m in messages if m.topic in classes]
    if not messages:
        raise BagError(f"bag {bag}: no messages to replay" + (
            f" (no Python message type for {', '.join(skipped)})" if skipped else ""))

    import rclpy
    from rclpy.duration import Duration
    from rclpy.signals import SignalHandlerOptions

    own = context is None
    if own:
        context = rclpy.Context()
        # Ctrl-C raises KeyboardInterrupt here (no rclpy handler): the finally below cleans up.
        rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    node = None
    try:
        node = rclpy.create_node("rbc_bag_replay", context=context,
                                 start_parameter_services=False)
        publishers = {t: node.create_publisher(c, t, replay_qos(t)) for t, c in classes.items()}
        _wait_for_subscribers(publishers, wait, log)
        started = time.monotonic()
        published, passes = _play(messages, publishers, rate, loop, progress, max_gap, log)
        seconds = time.monotonic() - started
        for pub in publishers.values():  # reliable delivery before the publishers go away
            pub.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))
        return ReplayResult(published, len(publishers), seconds, passes)
    finally:
        if node is not None:
            node.destroy_node()
        if own:
            rclpy.try_shutdown(context=context)


def replay_qos(topic: str) -> Any:
    """The QoS ``topic`` is replayed with: reliable, keep-all (a slow subscriber delays the
    replay instead of losing messages; the node's inputs are reliable, keep-all); volatile, but
    :data:`LATCHED_TOPICS` transient-local, as tf2 publishes and listens to ``/tf_static`` (a
    volatile publisher never reaches a tf2 static listener)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if topic in LATCHED_TOPICS
                      else DurabilityPolicy.VOLATILE)


def schedule(log_ns: Sequence[int], rate: float, max_gap: float) -> tuple[list[float], str]:
    """The wall-clock offset [s] of each message from the first: its receive time divided by
    ``rate``, with every gap longer than ``max_gap`` seconds (after the rate) shortened to it
    (one message logged 30 days late made a replay sleep silently for days).

    :return: the offsets, and one line naming the shortened gaps (empty when none).
    """
    offsets, total, shortened = [0.0], 0.0, []
    for k in range(1, len(log_ns)):
        gap = (log_ns[k] - log_ns[k - 1]) * 1e-9 / rate
        if gap > max_gap:
            shortened.append((gap, k))
            gap = max_gap
        total += max(gap, 0.0)
        offsets.append(total)
    if not shortened:
        return offsets, ""
    longest, k = max(shortened)
    return offsets, (f"{len(shortened)} gap(s) between messages longer than --max-gap "
                     f"{max_gap:g} s (at --rate {rate:g}) shortened to it; the longest "
                     f"{longest * rate:.4g} s of receive time, before message {k + 1}")


def _play(messages: list[RawMessage], publishers: dict[str, Any], rate: float, loop: bool,
          progress: bool, max_gap: float = math.inf, log: Any = print) -> tuple[int, int]:
    offsets, line = schedule([m.log_ns for m in messages], rate, max_gap)
    if line:
        log(f"replay: {line}")
    published = passes = 0
    while True:
        bar = Progress("replay", len(messages), enabled=progress)
        start = time.monotonic()
        for m, offset in zip(messages, offsets):
            delay = start + offset - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            _publish(publishers[m.topic], m, published, len(messages), rate)
            published += 1
            bar.update()
        bar.done()
        passes += 1
        if not loop:
            return published, passes


def _refused() -> type:
    """rclpy's exception for a message the middleware refused (imported when one was)."""
    from rclpy._rclpy_pybind11 import RCLError

    return RCLError


def _publish(publisher: Any, message: RawMessage, published: int, total: int,
             rate: float) -> None:
    """Publish one message; while the subscribers are too slow to take it (the middleware
    refuses it once their history is full), wait for them to acknowledge what was sent and
    try again, so nothing is lost; a ValueError naming the topic after :data:`STALL_TIMEOUT_S`
    without progress. A message taken at once costs the publish alone."""
    deadline: Optional[float] = None
    while True:
        try:
            publisher.publish(message.data)
            return
        except _refused() as exc:                   # looked up only when publish raised
            from rclpy.duration import Duration

            now = time.monotonic()
            deadline = now + STALL_TIMEOUT_S if deadline is None else deadline
            if now > deadline:
                raise ValueError(
                    f"publishing on {terminal(message.topic)} failed after {published} of "
                    f"{total} message(s): its subscribers took nothing for "
                    f"{STALL_TIMEOUT_S:g} s ({str(exc).splitlines()[0]}); is one of them "
                    f"stopped? (at --rate {rate:g})") from None
            publisher.wait_for_all_acked(Duration(seconds=0.05))
