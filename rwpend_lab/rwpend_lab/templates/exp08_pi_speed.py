"""Experiment 8 (Section 3.6): PI speed control (3.14) with the gains (3.15)-(3.16).

Run it:  ./rwpend lab run 8 --law THIS_FILE.py

A class keeps its state (the integral) between samples: Law(params) is built once, then
law(state) is called every sample (state and params as in the Experiment 7 template).
params: 'kdr', 'ki' (per-sample integral gain, ERRATA E15: k_i = omega0^2 h / b_r),
'times', 'refs' (the reference schedule: refs[i] from times[i] s on), and the rig's values.
"""


class Law:
    def __init__(self, params):
        self.p = params
        self.integral = 0.0

    def reference(self, t):
        ref = 0.0
        for ti, ri in zip(self.p['times'], self.p['refs']):
            if t >= ti:
                ref = ri
        return ref

    def __call__(self, state):
        raise NotImplementedError('write (3.14) here: e = ref - w; integral += ki e; u = kdr e + integral')
