"""The ROS 2 layer of rbc_registration (rclpy and message packages): ``registration_node``
(:mod:`.node`, :mod:`.services`), message <-> numpy conversions (:mod:`.conversions`), the
parameters as ROS parameters (:mod:`.params`), the status, diagnostics and marker messages
(:mod:`.status`, :mod:`.markers`), bag replay (:mod:`.replay`), node processes
(:mod:`.process`) and the demo (:mod:`.demo`). Everything below it (pipeline, io, core) never
imports rclpy.

Importing this package defaults BLAS to one thread, before the node module loads numpy: see
:mod:`rbc_registration.runtime`.
"""

from ..runtime import default_one_blas_thread

default_one_blas_thread()
