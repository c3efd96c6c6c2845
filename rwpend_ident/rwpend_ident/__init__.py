"""Identification of a rig: from a new Reaction Wheel Pendulum to its rig YAML (``./rwpend identify``)."""
