"""Experiment 12 (Chapter 4): stabilize the upright pendulum with the PD law (4.2),
u = -k_pp x - k_dp theta',  x = theta - pi wrapped to (-pi, pi] (theta is measured from hanging).

Run it:  ./rwpend lab run 12 --law THIS_FILE.py

params: 'kpp', 'kdp' from (4.3) with omega0 = omega_p, zeta = 1 -- negative numbers (ERRATA E18)
-- and the rig's values; state as in the Experiment 7 template.
"""
import math


def control(state, params):
    x = math.remainder(state.theta - math.pi, 2 * math.pi)
    raise NotImplementedError('write (4.2) here with x')
