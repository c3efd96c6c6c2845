"""Thin ROS glue shared by the rwpend nodes (QoS, rig parameters, executor, diagnostics)."""
