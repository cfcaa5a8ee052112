"""What ``registration_node`` and the offline tools share, below the ROS layer: the settings
(:mod:`.settings`), ingestion and its counters (:mod:`.ingest`), the served model state
(:mod:`.state`) and the debounced recompute worker (:mod:`.worker`), the journal
(:mod:`.journal`) and calibration snapshot (:mod:`.snapshot`), and offline evaluation
(:mod:`.offline`). numpy, scipy and the standard library only: never rclpy or a message package.
"""
