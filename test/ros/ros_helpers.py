"""Helpers of the ROS tests: a small synthetic cell in metres, the expected answers from the core
library on the same data, an rclpy harness (own Context, executor thread, client node) with a
base class that gives each test class its own, and node processes
(:mod:`rbc_registration.ros.process`) with the tests' defaults.

Imported by the tests and by the helper scripts run as separate processes. The rclpy parts are
imported lazily so that ``make_cell`` / ``expected_model`` stay usable without ROS.
"""

from __future__ import annotations

import os
import threading
import time
from typing import Any, Callable, Optional, Sequence

import numpy as np

from rbc_registration.core.measurements.accumulator import FiducialAccumulator
from rbc_registration.pipeline.settings import Settings
from rbc_registration.pipeline.state import build_state
from rbc_registration.ros.process import start_node, stop_process

__all__ = ["RosHarness", "RosTestBase", "answer_key", "expected_state", "make_cell",
           "pair_msg", "point_xyz", "start_test_node", "stop_process", "target_msg", "wait_for"]

WORKING_FRAME = "tracker"
DESTINATION_FRAME = "world"


def make_cell(seed: int = 0, repeats: int = 3, n_targets: int = 8, noise: float = 5e-5,
              bias: float = 1e-3) -> dict[str, np.ndarray]:
    """A 4 x 4 x 3 grid of holes 0.3 m apart (metres). Destination (world) holds the truth;
    the working frame (tracker) is a rigid motion of it plus a smooth bias of ~``bias`` m plus
    noise ``noise`` m per axis and measurement.

    :return: ``ids`` (J,), ``working`` (J * repeats, 3) measurements in visit order,
        ``destination`` (J * repeats, 3), ``fid`` (J * repeats,) index of the fiducial, and
        ``targets`` (K, 3) in the working frame, inside the grid.
    """
    rng = np.random.default_rng(seed)
    truth = np.array([[x, y, z] for x in range(4) for y in range(4) for z in range(3)],
                     dtype=np.float64) * 0.3
    angle = 0.4
    rot = np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0],
                    [0.0, 0.0, 1.0]])
    shift = np.array([1.2, -0.4, 0.8])

    def to_working(points: np.ndarray) -> np.ndarray:  # world -> tracker, plus bias
        w = (points - shift) @ rot
        field = np.column_stack([np.sin(2.0 * w[:, 0] + 1.0), np.cos(1.5 * w[:, 1]),
                                 np.sin(w[:, 0] + w[:, 2])])
        return w + bias * field

    fid = np.tile(np.arange(len(truth)), repeats)  # visit every hole, then again
    working = to_working(truth[fid]) + rng.normal(0.0, noise, (len(fid), 3))
    targets_true = rng.uniform([0.1, 0.1, 0.1], [0.8, 0.8, 0.5], (n_targets, 3))
    return {"ids": np.array([f"H{k:02d}" for k in range(len(truth))]), "fid": fid,
            "working": working, "destination": truth[fid].copy(),
            "targets": to_working(targets_true)}


def expected_state(cell: dict[str, np.ndarray], indices: Optional[Sequence[int]] = None,
                   with_ids: bool = True, **settings: Any):
    """The model the node should build from the pairs ``indices`` (default: all) of ``cell``
    (the same accumulator and builder the node uses; ``with_ids=False``: ids by proximity)."""
    s = Settings.from_mapping({"working_frame": WORKING_FRAME,
                               "destination_frame": DESTINATION_FRAME, **settings})
    acc = FiducialAccumulator(s.dimension, s.working_frame, s.destination_frame, s.merge_radius,
                              s.outlier_distance)
    for k in range(len(cell["fid"])) if indices is None else indices:
        fid = str(cell["ids"][cell["fid"][k]]) if with_ids else None
        acc.add(fid, cell["working"][k], cell["destination"][k])
    return build_state(acc.fiducial_set(), s, 0)


def wait_for(predicate: Callable[[], bool], timeout: float = 10.0, what: str = "") -> None:
    """Poll ``predicate`` until true; AssertionError after ``timeout`` seconds."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if predicate():
            return
        time.sleep(0.01)
    raise AssertionError(f"timed out after {timeout} s waiting for {what or predicate}")


def domain_id() -> int:
    """The ROS domain of this test process (the user's, or chosen by test/conftest.py)."""
    return int(os.environ.get("ROS_DOMAIN_ID", "0"))


class RosHarness:
    """An rclpy Context with a multi-threaded executor spinning in a thread and a client node.

    Use ``start()`` / ``stop()`` (stop joins the spin thread before shutting the context down).
    """

    def __init__(self) -> None:
        import rclpy
        from rclpy.executors import MultiThreadedExecutor

        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id())
        self.executor = MultiThreadedExecutor(num_threads=4, context=self.context)
        self.client = rclpy.create_node("test_client", context=self.context)
        self.executor.add_node(self.client)
        self._clients: dict[str, Any] = {}
        self._stopping = False
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        """``executor.spin()`` that survives the tests destroying their subscriptions and
        publishers from the test thread: rclpy then raises ``InvalidHandle`` in the spin thread
        when it was collecting that entity for its wait set, which ended ``spin()`` and left
        every later service call of the class unanswered (seen as a 30 s timeout)."""
        from rclpy._rclpy_pybind11 import InvalidHandle
        from rclpy.executors import ExternalShutdownException, ShutdownException

        while not self._stopping and self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.1)
            except InvalidHandle:
                continue   # the wait set is collected again without the destroyed entity
            except (ShutdownException, ExternalShutdownException):
                return

    def add(self, node: Any) -> Any:
        """Spin ``node`` too; returns it."""
        self.executor.add_node(node)
        return node

    def remove(self, node: Any) -> None:
        """Stop spinning ``node`` and destroy it."""
        self.executor.remove_node(node)
        node.destroy_node()

    def call(self, srv_type: Any, name: str, request: Any, timeout: float = 10.0) -> Any:
        """Call service ``name`` from the client node and return the response."""
        client = self._clients.get(name)
        if client is None:
            client = self._clients[name] = self.client.create_client(srv_type, name)
        assert client.wait_for_service(timeout_sec=timeout), f"service {name} not available"
        future = client.call_async(request)
        done = threading.Event()
        future.add_done_callback(lambda _: done.set())
        assert done.wait(timeout), f"service {name} did not answer within {timeout} s"
        return future.result()

    def stop(self) -> None:
        """Shut the executor down, join its thread, destroy the client, shut the context down."""
        import rclpy

        self._stopping = True
        self.executor.shutdown()
        self._thread.join(timeout=10.0)
        self.client.destroy_node()
        rclpy.shutdown(context=self.context)


class RosTestBase:
    """Base of the in-process ROS test classes: one :class:`RosHarness` (own Context) per class,
    as ``cls.ros``, stopped after the class's last test."""

    ros: RosHarness

    @classmethod
    def setup_class(cls) -> None:
        cls.ros = RosHarness()

    @classmethod
    def teardown_class(cls) -> None:
        cls.ros.stop()


#: The tests' node processes recompute quickly.
TEST_NODE_PARAMS = {"debounce_period": 0.05}


def start_test_node(name: str, state_dir: Any = None, log: Any = None, **options: Any):
    """:func:`rbc_registration.ros.process.start_node` with the tests' parameters
    (``debounce_period:=0.05``, ``state_dir`` when given, else none: no persistence); keyword
    arguments that are not options of ``start_node`` are node parameters."""
    keys = ("env", "ros_args", "command", "popen")
    params = {**TEST_NODE_PARAMS, "state_dir": state_dir or "''",
              **{k: v for k, v in options.items() if k not in keys}}
    return start_node(name, params, log=log, **{k: v for k, v in options.items() if k in keys})


def pair_msg(cell: dict[str, np.ndarray], k: int, with_id: bool = True, stamp_s: float = 0.0,
             frame: str = WORKING_FRAME, destination_frame: str = DESTINATION_FRAME) -> Any:
    """FiducialPair message for measurement ``k`` of ``cell``."""
    from geometry_msgs.msg import Point
    from rbc_registration_interfaces.msg import FiducialPair

    msg = FiducialPair()
    msg.header.frame_id = frame
    msg.header.stamp.sec = int(stamp_s)
    msg.header.stamp.nanosec = int(round((stamp_s - int(stamp_s)) * 1e9))
    msg.fiducial_id = str(cell["ids"][cell["fid"][k]]) if with_id else ""
    msg.working_point = Point(x=float(cell["working"][k][0]), y=float(cell["working"][k][1]),
                              z=float(cell["working"][k][2]))
    msg.destination_frame_id = destination_frame
    msg.destination_point = Point(x=float(cell["destination"][k][0]),
                                  y=float(cell["destination"][k][1]),
                                  z=float(cell["destination"][k][2]))
    return msg


def target_msg(xyz: Any, frame: str = WORKING_FRAME) -> Any:
    """PointStamped target in the working frame."""
    from geometry_msgs.msg import PointStamped

    msg = PointStamped()
    msg.header.frame_id = frame
    msg.point.x, msg.point.y, msg.point.z = (float(v) for v in xyz)
    return msg


def point_xyz(point: Any) -> np.ndarray:
    """geometry_msgs Point / Vector3 -> (3,)."""
    return np.array([point.x, point.y, point.z])


def answer_key(response: Any) -> tuple:
    """A CorrectTarget response / TargetCorrection as a comparable tuple (NaN -> None)."""
    def num(v: float) -> Optional[float]:
        return None if v != v else v
    return (getattr(response, "success", True), tuple(point_xyz(response.destination.point)),
            tuple(point_xyz(response.corrected.point)),
            tuple(point_xyz(response.uncorrected.point)),
            tuple(point_xyz(response.correction)), response.correction_applied,
            response.inside_hull, num(response.expected_error), response.method,
            num(response.expected_tre), num(response.tre_bound))
