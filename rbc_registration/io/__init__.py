"""Readers and writers: CSV, JSON reports, figures, rosbag2. Never imports rclpy."""
