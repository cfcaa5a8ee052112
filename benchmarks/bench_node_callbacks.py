"""The node's own cost per callback, in process (no DDS round trip): ``~/correct_target``
(incl. the ``CorrectTarget.Response()`` rclpy builds) and ``~/fiducial_pairs`` (journal on),
5 blocks each, min and median [us]. Compare trees by running it with ``PYTHONPATH=<tree>``
(it prints which tree it loaded), alternating.

    source scripts/env.sh && python benchmarks/bench_node_callbacks.py
"""
import os
import sys
import tempfile
import time

os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_STATIC_PEERS", None)
os.environ.setdefault("ROS_DOMAIN_ID", str(os.getpid() % 101 + 1))
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "test", "ros"))
import rbc_registration  # noqa: E402
import rclpy  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from ros_helpers import make_cell, pair_msg, target_msg  # noqa: E402
from rbc_registration.ros.node import RegistrationNode  # noqa: E402
from rbc_registration_interfaces.srv import CorrectTarget  # noqa: E402
ctx = Context()
rclpy.init(context=ctx)
node = RegistrationNode("inproc", context=ctx, parameter_overrides=[
    Parameter("state_dir", value=tempfile.mkdtemp()), Parameter("outlier_distance", value=0.0)])
cell = make_cell(seed=0, repeats=3)
for k in range(len(cell["fid"])):
    node._on_fiducial_pair(pair_msg(cell, k, stamp_s=1.0 + k * 1e-3))
node._worker.wait(node._worker.request_now(), 30)
reqs = [CorrectTarget.Request(target=target_msg(t)) for t in cell["targets"]]
big = make_cell(seed=1, repeats=50)
rt, ing = [], []
for run in range(5):
    # new stamps every run: the same message again is a duplicate, rejected (not ingestion)
    msgs = [pair_msg(big, k, with_id=False, stamp_s=10.0 + run * 100.0 + k * 1e-4)
            for k in range(2400)]
    t = time.perf_counter()
    for k in range(2000):
        node._on_correct_target(reqs[k % len(reqs)], CorrectTarget.Response())
    rt.append((time.perf_counter() - t) / 2000 * 1e6)
    t = time.perf_counter()
    for m in msgs:
        node._on_fiducial_pair(m)
    ing.append((time.perf_counter() - t) / len(msgs) * 1e6)
    node._worker.wait(node._worker.request_now(), 30)
print(f"{os.path.dirname(os.path.dirname(rbc_registration.__file__))}: correct_target callback "
      f"(incl. Response()) min {min(rt):.1f} median {sorted(rt)[2]:.1f} us; ingestion callback "
      f"min {min(ing):.1f} median {sorted(ing)[2]:.1f} us")
node.destroy_node()
rclpy.shutdown(context=ctx)
