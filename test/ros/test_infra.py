"""Smoke test of the build: the generated interfaces work with rclpy on loopback, in process."""

import math
import os
import threading

import pytest

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

TIMEOUT = 10.0  # [s] generous: discovery on a loaded 2-core CI machine


@pytest.mark.ros
class TestInterfacesInProcess:
    """One node offers the services and publishes; a second node is the client and subscriber."""

    @classmethod
    def setup_class(cls):
        import rclpy
        from rclpy.executors import MultiThreadedExecutor
        from rbc_registration_interfaces.srv import SetFiducialEnabled

        cls.context = rclpy.Context()
        rclpy.init(context=cls.context)
        cls.server = rclpy.create_node('infra_server', context=cls.context)
        cls.client_node = rclpy.create_node('infra_client', context=cls.context)
        cls.disabled = set()
        cls.service = cls.server.create_service(
            SetFiducialEnabled, 'set_fiducial_enabled', cls._on_set_fiducial_enabled)
        cls.executor = MultiThreadedExecutor(num_threads=2, context=cls.context)
        cls.executor.add_node(cls.server)
        cls.executor.add_node(cls.client_node)
        cls.spin_thread = threading.Thread(target=cls.executor.spin, daemon=True)
        cls.spin_thread.start()

    @classmethod
    def teardown_class(cls):
        import rclpy

        # Stop and join the spinning thread before shutdown, or the process may abort (rc 134).
        cls.executor.shutdown(timeout_sec=TIMEOUT)
        cls.spin_thread.join(timeout=TIMEOUT)
        assert not cls.spin_thread.is_alive()
        cls.server.destroy_node()
        cls.client_node.destroy_node()
        rclpy.shutdown(context=cls.context)

    @classmethod
    def _on_set_fiducial_enabled(cls, request, response):
        if request.fiducial_id != 'H12-07':
            response.success = False
            response.message = f'unknown fiducial id {request.fiducial_id!r}'
            return response
        if request.enabled:
            cls.disabled.discard(request.fiducial_id)
        else:
            cls.disabled.add(request.fiducial_id)
        response.success = True
        response.message = ''
        return response

    def _call(self, client, request):
        done = threading.Event()
        future = client.call_async(request)
        future.add_done_callback(lambda _: done.set())
        assert done.wait(TIMEOUT), 'no service response'
        return future.result()

    def test_environment_keeps_dds_on_loopback(self):
        assert os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
        if os.environ['ROS_DOMAIN_ID'] == os.environ.get('RBC_CHOSEN_ROS_DOMAIN_ID'):
            assert 1 <= int(os.environ['ROS_DOMAIN_ID']) <= 101     # chosen, not the user's
        assert self.context.get_domain_id() == int(os.environ['ROS_DOMAIN_ID'])

    def test_set_fiducial_enabled_service(self):
        from rbc_registration_interfaces.srv import SetFiducialEnabled

        client = self.client_node.create_client(SetFiducialEnabled, 'set_fiducial_enabled')
        try:
            assert client.wait_for_service(timeout_sec=TIMEOUT)
            response = self._call(
                client, SetFiducialEnabled.Request(fiducial_id='H12-07', enabled=False))
            assert response.success
            assert self.disabled == {'H12-07'}
            response = self._call(
                client, SetFiducialEnabled.Request(fiducial_id='nope', enabled=True))
            assert not response.success
            assert 'nope' in response.message
        finally:
            self.client_node.destroy_client(client)

    def test_fiducial_pair_publish_and_receive(self):
        from geometry_msgs.msg import Point
        from rbc_registration_interfaces.msg import FiducialPair
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        qos = QoSProfile(
            depth=10, reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL)
        received = []
        got_one = threading.Event()

        def on_pair(msg):
            received.append(msg)
            got_one.set()

        publisher = self.server.create_publisher(FiducialPair, 'fiducial_pairs', qos)
        subscription = self.client_node.create_subscription(
            FiducialPair, 'fiducial_pairs', on_pair, qos)
        try:
            sent = FiducialPair(
                fiducial_id='H12-07',
                working_point=Point(x=0.1, y=-0.2, z=0.3),
                destination_frame_id='world',
                destination_point=Point(x=1.5, y=2.5, z=math.nan))
            sent.header.frame_id = 'tracker'
            sent.header.stamp.sec = 42
            publisher.publish(sent)
            assert got_one.wait(TIMEOUT), 'no FiducialPair received'
            msg = received[0]
            assert msg.fiducial_id == 'H12-07'
            assert msg.header.frame_id == 'tracker' and msg.header.stamp.sec == 42
            assert (msg.working_point.x, msg.working_point.y, msg.working_point.z) == (
                0.1, -0.2, 0.3)
            assert msg.destination_frame_id == 'world'
            assert msg.destination_point.x == 1.5 and math.isnan(msg.destination_point.z)
        finally:
            self.client_node.destroy_subscription(subscription)
            self.server.destroy_publisher(publisher)


@pytest.mark.ros
def test_every_interface_round_trips_through_serialization():
    """The typesupport of every message and service part loads and (de)serializes."""
    from geometry_msgs.msg import PointStamped
    from rbc_registration_interfaces.msg import FiducialPair, RegistrationStatus, TargetCorrection
    from rbc_registration_interfaces.srv import CorrectTarget, CorrectTargets, SetFiducialEnabled
    from rclpy.serialization import deserialize_message, serialize_message

    status = RegistrationStatus(dimension=3, sigma_l=[1e-3, 5e-4], recommendation='apply')
    targets = CorrectTargets.Request(targets=[PointStamped(), PointStamped()])
    results = CorrectTargets.Response(
        success=True, results=[TargetCorrection(expected_error=math.nan, inside_hull=True)])
    messages = [
        FiducialPair(fiducial_id='a'), status, TargetCorrection(correction_applied=True),
        CorrectTarget.Request(), CorrectTarget.Response(message='no model'),
        targets, results, SetFiducialEnabled.Request(fiducial_id='b'),
        SetFiducialEnabled.Response(success=True),
    ]
    for msg in messages:
        back = deserialize_message(serialize_message(msg), type(msg))
        if msg is results:
            assert back.success and back.results[0].inside_hull
            assert math.isnan(back.results[0].expected_error)
        else:
            assert back == msg
    assert list(deserialize_message(serialize_message(status), RegistrationStatus).sigma_l) == [
        1e-3, 5e-4]


@pytest.mark.ros
def test_package_share_directory_is_indexed():
    """The installed package is in the ament index (launch and config files are found)."""
    from ament_index_python.packages import get_package_share_directory

    share = get_package_share_directory('rbc_registration')
    assert os.path.isfile(os.path.join(share, 'package.xml'))
    assert os.path.isfile(os.path.join(share, 'config', 'registration_node.yaml'))
    assert os.path.isfile(os.path.join(share, 'launch', 'registration.launch.py'))
    get_package_share_directory('rbc_registration_interfaces')


def test_every_source_directory_is_a_package():
    """find_packages() skips directories without __init__.py, so colcon would not install them."""
    from setuptools import find_packages

    found = set(find_packages(where=REPO, exclude=['test', 'test.*']))
    source_dirs = set()
    for root, dirs, files in os.walk(os.path.join(REPO, 'rbc_registration')):
        dirs[:] = [d for d in dirs if d != '__pycache__']
        if any(f.endswith('.py') for f in files):
            source_dirs.add(os.path.relpath(root, REPO).replace(os.sep, '.'))
    assert source_dirs - found == set(), 'add an __init__.py to these'
