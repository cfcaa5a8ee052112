"""The ROS 2 side of rbc_registration: ``registration_node`` (:mod:`.node`), message <-> numpy
conversions, parameters, persistence and reports. Imports rclpy; :mod:`rbc_registration.core`
never does."""
