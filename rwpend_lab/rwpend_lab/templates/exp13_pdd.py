"""Experiment 13 (Section 4.2): stabilization and control of the wheel velocity (4.9),
u = -k_pp x - k_dp theta' - k_dr theta_r'   (omega_ref = 0).

Run it:  ./rwpend lab run 13 --law THIS_FILE.py   (the three gain sets of (4.11) in turn)

params: 'kpp', 'kdp', 'kdr' (negative, (4.11)) and the rig's values; state as in the
Experiment 7 template; x = math.remainder(state.theta - math.pi, 2 * math.pi).
"""
import math


def control(state, params):
    raise NotImplementedError('write (4.9) here')
