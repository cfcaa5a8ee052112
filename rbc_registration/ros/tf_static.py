"""The node's own latched ``/tf_static`` publisher: a ``tf2_msgs/TFMessage`` that always holds
the node's current registration (destination ← working), replaced on every model and emptied of
it on reset.

tf2_ros_py's ``StaticTransformBroadcaster`` is not used: it keeps the first transform of a child
frame and ignores later sends of the same child, so tf users would keep the first model. tf2
listeners merge the latched messages of every ``/tf_static`` publisher, so this publisher holds
only the node's own frames: its working frame, and the named targets of ``target_frames`` at
their corrected destinations (:func:`target_transforms`). QoS as tf2's static broadcaster:
reliable, TRANSIENT_LOCAL, depth 1 (a late joiner gets the newest message only).
"""

from __future__ import annotations

from typing import Any, Iterable, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike

from geometry_msgs.msg import TransformStamped
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from .outputs import output_events

try:  # tf2_msgs is a ROS package (not on PyPI; the development venv builds vendor/tf2_msgs)
    from tf2_msgs.msg import TFMessage
    MISSING = ""
except ImportError as _exc:  # pragma: no cover - depends on the installation
    TFMessage = None
    MISSING = f"tf2_msgs is not importable ({_exc})"

TOPIC = "/tf_static"
STATIC_QOS = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)


class StaticTf:
    """The latched ``/tf_static`` message of one node: one entry per child frame.

    :param node: the ``rclpy.node.Node`` that publishes.
    :param message_type: the TFMessage class (default ``tf2_msgs.msg.TFMessage``; ``None``: tf is
        off and :attr:`missing` says why).
    """

    def __init__(self, node: Any, message_type: Optional[Any] = TFMessage) -> None:
        self._type = message_type
        self.missing = MISSING if message_type is None else ""
        self._entries: dict[str, TransformStamped] = {}
        self._pub = (node.create_publisher(message_type, TOPIC, STATIC_QOS,
                                           event_callbacks=output_events())
                     if message_type is not None else None)

    @property
    def available(self) -> bool:
        """Whether a ``/tf_static`` publisher exists."""
        return self._pub is not None

    def set(self, transform: TransformStamped) -> None:
        """Replace the entry of ``transform.child_frame_id`` and publish."""
        self._entries[transform.child_frame_id] = transform
        self._publish()

    def remove(self, child_frame: str) -> None:
        """Drop the entry of ``child_frame`` and publish the message without it."""
        if self._entries.pop(child_frame, None) is not None:
            self._publish()

    def replace(self, transforms: Sequence[TransformStamped], remove: Iterable[str] = ()
                ) -> None:
        """Set the entries of ``transforms``, drop those of the child frames ``remove`` (not
        among ``transforms``), and publish once."""
        for child in remove:
            self._entries.pop(child, None)
        for transform in transforms:
            self._entries[transform.child_frame_id] = transform
        self._publish()

    def transforms(self) -> list[TransformStamped]:
        """The entries published now."""
        return list(self._entries.values())

    def _publish(self) -> None:
        if self._pub is not None:
            self._pub.publish(self._type(transforms=self.transforms()))


def target_transforms(names: Sequence[str], destinations: ArrayLike, parent_frame: str,
                      stamp: Any) -> list[TransformStamped]:
    """The ``/tf_static`` entries of named targets: child frame ``names[k]`` of
    ``parent_frame`` (destination_frame) at ``destinations[k]`` (K, 3) [m], with the parent's
    axes (identity rotation: a target is a point)."""
    out = []
    for name, xyz in zip(names, np.asarray(destinations, dtype=np.float64).tolist(),
                         strict=True):
        msg = TransformStamped()
        msg.header.frame_id, msg.header.stamp, msg.child_frame_id = parent_frame, stamp, name
        t = msg.transform.translation
        t.x, t.y, t.z = xyz
        msg.transform.rotation.w = 1.0
        out.append(msg)
    return out
