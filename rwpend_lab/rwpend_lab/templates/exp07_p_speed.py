"""Experiment 7 (Section 3.5): velocity control with proportional feedback, u = k_dr (w_r - w) (3.13).

Run it:  ./rwpend lab run 7 --law THIS_FILE.py

control(state, params) is called by the controller node every sample h:
  state.t            s since the law was switched on
  state.theta, state.theta_dot        pendulum (rad, rad/s; locked on the bracket: 0)
  state.wheel_angle, state.wheel_rate wheel (rad, rad/s)
  state.friction     the estimator's friction estimate (control units)
  params             'kdr', 'ref' (the run's gain and reference speed, rad/s) and the rig's
                     'a', 'b_p', 'b_r', 'omega_p', 'h', 'u_max', 'k_u'
Return u in control units (|u| <= u_max is enforced for you).  An exception or a non-finite
u stops the law: u = 0 and the reason on controller/status.
"""


def control(state, params):
    raise NotImplementedError('write (3.13) here: u = k_dr (w_r - w)')
