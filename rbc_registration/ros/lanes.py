"""The executor of ``registration_node``: single-threaded, except that the callbacks of chosen
callback groups run each group in a thread of its own (a *lane*).

rclpy takes a service request (deserialises it into Python objects) in the thread that runs its
callback, so on a plain ``SingleThreadedExecutor`` one large ``~/correct_targets`` request
holds every other callback for as long as it is taken and answered (about 47 us per target).
With ``~/correct_target`` and ``~/correct_targets`` each in a lane, a client's single-target
correction waits for neither another client's many-target request nor the message intake; the
rest keeps the single spin thread, which takes messages about twice as fast as rclpy's
multi-threaded executor. The lanes share the GIL with the spin thread.
"""

from __future__ import annotations

import threading
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, Callable, Optional

from rclpy.callback_groups import CallbackGroup
from rclpy.executors import (ConditionReachedException, ExternalShutdownException,
                             ShutdownException, SingleThreadedExecutor, TimeoutException)


def _run(handler: Any) -> None:
    """Run an executor task (a handler of :meth:`LaneExecutor.wait_for_ready_callbacks`) and
    raise what its callback raised."""
    handler()
    exception = handler.exception()
    if exception is not None:
        raise exception


class LaneExecutor(SingleThreadedExecutor):
    """A ``SingleThreadedExecutor`` whose :meth:`add_lane` groups run in their own threads.

    A group's callbacks still run one at a time when the group is mutually exclusive (rclpy
    does not hand out a busy group's next callback). An exception raised in a lane is raised
    again by the spin thread's next :meth:`spin_once`, as rclpy's executors do.
    """

    def __init__(self, *, context: Any = None) -> None:
        super().__init__(context=context)
        self._lanes: dict[CallbackGroup, ThreadPoolExecutor] = {}
        self._lane_lock = threading.Lock()
        self._running: list[Future] = []

    def add_lane(self, group: CallbackGroup, name: str) -> None:
        """Run the callbacks of ``group`` in a thread of its own, named ``name``."""
        with self._lane_lock:
            if group not in self._lanes:
                self._lanes[group] = ThreadPoolExecutor(1, thread_name_prefix=name)

    def _spin_once_impl(self, timeout_sec: Optional[float] = None,
                        wait_condition: Callable[[], bool] = lambda: False) -> None:
        self._raise_lane_errors()
        try:
            handler, entity, _node = self.wait_for_ready_callbacks(timeout_sec, None,
                                                                   wait_condition)
        except (ExternalShutdownException, ShutdownException, TimeoutException,
                ConditionReachedException):
            return
        lane = self._lanes.get(getattr(entity, "callback_group", None))
        if lane is None:
            _run(handler)
            return
        with self._lane_lock:
            self._running.append(lane.submit(_run, handler))

    def _raise_lane_errors(self) -> None:
        with self._lane_lock:
            done = [f for f in self._running if f.done()]
            self._running = [f for f in self._running if not f.done()]
        for future in done:
            future.result()            # a lane's exception, in the spin thread

    def shutdown(self, timeout_sec: Optional[float] = None) -> bool:
        """Stop executing callbacks, then join the lane threads (their callbacks finish)."""
        success = super().shutdown(timeout_sec)
        with self._lane_lock:
            lanes, self._lanes = list(self._lanes.values()), {}
        for lane in lanes:
            lane.shutdown(wait=True)
        return success
