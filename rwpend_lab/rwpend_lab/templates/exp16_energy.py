"""Experiment 16 (Section 5.3): swing up with the energy (passivity) controller (5.21)/(6.1),
u = sat(c_e (E - E_ref) theta' - c_v theta_r'),  E = 1 - cos(theta) + (theta'/omega_p)^2 / 2 (6.2)
(signs and units as in ERRATA E34-E35: pumping needs u theta' < 0).

Run it:  ./rwpend lab run 16 --law THIS_FILE.py

params: 'c_e', 'c_v' (from k_e = 4000, k_v = 4, k_u = 0.4), 'e_ref' and the rig's values
('omega_p', ...); state as in the Experiment 7 template.
"""
import math


def control(state, params):
    raise NotImplementedError('write the energy controller here; what E_ref swings it up?')
