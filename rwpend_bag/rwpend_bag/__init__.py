"""Recorder, player, inspector and analyser of rosbag2 MCAP bags."""
