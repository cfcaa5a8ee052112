"""The ROS 2 side of rbc_registration: ``registration_node`` (:mod:`.node`), message <-> numpy
conversions, parameters, persistence and reports. Imports rclpy; :mod:`rbc_registration.core`
never does.

The node calls BLAS from two threads (services and the recompute thread). OpenBLAS's own worker
threads spin-wait and, on a busy machine, stalled the whole node for seconds (benchmarks/RESULTS.md,
"Soak"); one BLAS thread is the default here, set before numpy is first imported. Set
``OPENBLAS_NUM_THREADS`` yourself to override it.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
