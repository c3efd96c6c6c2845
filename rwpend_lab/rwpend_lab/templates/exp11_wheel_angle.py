"""Experiment 11 (Section 3.9): wheel-angle control (3.18), u = k_pr (theta_ref - theta_r) - k_dr theta_r'.

Run it:  ./rwpend lab run 11 --law THIS_FILE.py

params: 'kpr', 'kdr' (designed for the run's omega0 and zeta), 'ref' (rad, relative to the
start), and the rig's values; state as in the Experiment 7 template.
"""


def control(state, params):
    raise NotImplementedError('write (3.18) here')
