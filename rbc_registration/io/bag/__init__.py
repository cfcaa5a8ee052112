"""rosbag2 files of registration data, read and written with ``rosbags`` (no rclpy):
:mod:`.records` (topics, type names, records, :class:`~.records.BagError`; no rosbags import),
:mod:`.typestore` (type definitions), :mod:`.reader`, :mod:`.writer` and :mod:`.synthetic`
(a synthetic cell as the messages of a recorded bag). See docs/BAGS.md.
"""
