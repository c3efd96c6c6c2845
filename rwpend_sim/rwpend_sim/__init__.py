"""Simulated Reaction Wheel Pendulum node: publishes quantized encoder counts like the rig."""
