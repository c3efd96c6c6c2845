"""Experiment 10 (Section 3.8): friction compensation.  The wheel is spun by hand; add the friction
of your curve (Experiment 9, (3.17)) to u so that u - F = 0 and the wheel keeps turning.

Run it:  ./rwpend lab run 10 --law THIS_FILE.py   (replaces the run with compensation)

state, params: as in the Experiment 7 template; params has no gains for this run.
"""


def control(state, params):
    raise NotImplementedError('return F(w) of (3.17) at w = state.wheel_rate - state.theta_dot')
