"""Robustness studies of the rig: many closed-loop lockstep runs of the loop (./rwpend sweep)."""
