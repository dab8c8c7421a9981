"""The streams of a ROS bag that `--topic NAME=TOPIC` (`ReaderOptions.topics`) may read from
other topics: the reader (`backend.data.rosbag`) and the sweep's options
(`backend.sweep.matrix`) check names against this list without importing each other."""

from __future__ import annotations

TOPIC_NAMES = ("cam0", "cam1", "imu0", "groundtruth")
