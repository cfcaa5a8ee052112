"""tf2_msgs in the venv (vendor/tf2_msgs, built by scripts/bootstrap.sh) is the real message type:
its type hashes are upstream's, and a TFMessage goes through rclpy's middleware on loopback to a
late-joining subscriber of a TRANSIENT_LOCAL topic, as /tf_static is used."""

import json
import os
import threading

import pytest
from ros_helpers import RosTestBase

TIMEOUT = 10.0  # [s] generous: discovery on a loaded 2-core CI machine
TOPIC = '/rbc_test/tf_static'  # a topic of this test alone, with /tf_static's QoS

# Kilted's definitions as held by rosbags (maintained apart from vendor/tf2_msgs); the services and
# actions are not in its type store.
MESSAGES = ('tf2_msgs/msg/TFMessage', 'tf2_msgs/msg/TF2Error')


def _installed_hash(type_name: str) -> str:
    """The RIHS01 hash rosidl generated for ``type_name`` (share/<pkg>/<msg>/<Name>.json)."""
    from ament_index_python.packages import get_package_share_directory

    package, kind, name = type_name.split('/')
    path = os.path.join(get_package_share_directory(package), kind, f'{name}.json')
    with open(path, encoding='utf-8') as f:
        hashes = {h['type_name']: h['hash_string'] for h in json.load(f)['type_hashes']}
    return hashes[type_name]


def _upstream_hash(type_name: str) -> str:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_KILTED).hash_rihs01(type_name)


def test_every_interface_imports():
    from tf2_msgs.action import LookupTransform
    from tf2_msgs.msg import TF2Error, TFMessage
    from tf2_msgs.srv import FrameGraph

    assert TFMessage().transforms == []
    assert TF2Error.TRANSFORM_ERROR == 6 and TF2Error().error == TF2Error.NO_ERRORS
    assert FrameGraph.Response().frame_yaml == ''
    goal = LookupTransform.Goal(target_frame='world', source_frame='tracker', advanced=False)
    assert (goal.target_frame, goal.source_frame) == ('world', 'tracker')
    assert LookupTransform.Result().error.error == TF2Error.NO_ERRORS


@pytest.mark.parametrize('type_name', MESSAGES)
def test_type_hash_is_upstreams(type_name):
    # Equal RIHS01 hashes: same field names, types and order as Kilted's tf2_msgs, so a tf2 user
    # of a real installation (RViz, MoveIt, tf2_ros) matches this type on the wire.
    assert _installed_hash(type_name) == _upstream_hash(type_name)


@pytest.mark.ros
class TestTFMessageOnLoopback(RosTestBase):
    """A publisher latches one TFMessage; a subscriber created afterwards receives it."""

    @classmethod
    def setup_class(cls):
        import rclpy
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        cls.qos = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        super().setup_class()  # own Context, executor thread; its client node subscribes
        cls.pub_node = cls.ros.add(rclpy.create_node('tf2_msgs_probe_pub',
                                                     context=cls.ros.context))

    @classmethod
    def teardown_class(cls):
        cls.ros.remove(cls.pub_node)
        super().teardown_class()  # joins the spin thread before shutting the context down

    @staticmethod
    def _transform(parent, child, xyz, quat):
        from geometry_msgs.msg import TransformStamped

        t = TransformStamped()
        t.header.frame_id, t.child_frame_id = parent, child
        t.header.stamp.sec, t.header.stamp.nanosec = 1_700_000_000, 250_000_000
        t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = xyz
        r = t.transform.rotation
        r.x, r.y, r.z, r.w = quat
        return t

    def test_late_subscriber_receives_the_latched_message(self):
        from tf2_msgs.msg import TFMessage

        sent = TFMessage(transforms=[
            self._transform('world', 'tracker', (1.25, -0.5, 0.75), (0.0, 0.0, 0.6, 0.8)),
            self._transform('world', 'tool', (0.0, 2.0, -1e-4), (0.5, 0.5, 0.5, 0.5))])
        publisher = self.pub_node.create_publisher(TFMessage, TOPIC, self.qos)
        publisher.publish(sent)  # before any subscriber exists: only durability can deliver it

        received = []
        done = threading.Event()

        def on_message(msg):
            received.append(msg)
            done.set()

        self.ros.client.create_subscription(TFMessage, TOPIC, on_message, self.qos)
        assert done.wait(TIMEOUT), f'no TFMessage on {TOPIC} within {TIMEOUT} s'
        assert received[0] == sent  # every field, both transforms, in order

        infos = self.ros.client.get_publishers_info_by_topic(TOPIC)
        assert [i.topic_type for i in infos] == ['tf2_msgs/msg/TFMessage']
        assert str(infos[0].topic_type_hash) == _upstream_hash('tf2_msgs/msg/TFMessage')
