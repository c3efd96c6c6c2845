"""A run of the lab without ROS: the same simulator core, estimator and controller, in one loop.

Pure Python (no rclpy), for the unit tests of the analyses (synthetic data that look like a
bag of the stack) and for trying an experiment's settings quickly.  Per sample k, as in lockstep:
the encoders of t_k, the estimate (with the command held over the previous interval), the
controller's command answering k, then the plant integrates [t_k, t_k+1) with it.
"""
from __future__ import annotations

import numpy as np

from rwpend_control.supervisor import Controller, ControllerConfig, config_with
from rwpend_control.user_law import load_law
from rwpend_estimation.estimators import EstimatorConfig, make_estimator
from rwpend_sim.sim_core import SimCore

from .data import RunData
from .experiment import Run

#: sim parameter -> Plant keyword
_PLANT_ARGS = {'initial.theta': 'theta', 'initial.theta_dot': 'theta_dot',
               'initial.wheel_angle': 'wheel_angle', 'initial.wheel_rate': 'wheel_rate',
               'friction': 'friction', 'motor_lag': 'motor_lag', 'pwm': 'pwm', 'back_emf': 'back_emf',
               'bracket': 'bracket', 'torque_meter': 'rotor_locked'}


def sim_core(rig, sim: dict) -> SimCore:
    """The simulator core with the run's sim parameters (initial state, switches, taps, torques)."""
    kwargs = {_PLANT_ARGS[k]: v for k, v in sim.items() if k in _PLANT_ARGS}
    core = SimCore(rig, command_timeout_samples=3, **kwargs)
    if 'taps.times' in sim:
        core.schedule_taps(sim['taps.times'], sim['taps.sizes'])
    if 'torques.times' in sim:
        core.schedule_torques(sim['torques.times'], sim['torques.sizes'], sim['torques.durations'])
    return core


def controller(rig, run: Run) -> Controller:
    law = load_law(run.law, dict(run.law_params), rig) if run.law else None
    values = {k: v for k, v in run.controller.items() if not k.startswith('law.')}
    cfg = config_with(ControllerConfig.designed(rig), values)
    return Controller(rig, cfg, mode=run.mode, user_law=law)


def simulate(rig, run: Run, duration: float | None = None, plant_rig=None) -> RunData:
    """RunData of ``run`` simulated in pure Python (``duration`` overrides the run's; ``plant_rig``:
    the plant's truth when it differs from the rig the estimator and controller use)."""
    core = sim_core(plant_rig or rig, dict(run.sim))
    est = make_estimator(None, rig, EstimatorConfig.from_values(dict(run.estimator), rig=rig))
    ctrl = controller(rig, run)
    h = rig.sample_period
    n = int(round((run.duration if duration is None else duration) / h))
    rec = {k: np.zeros(n) for k in ('pc', 'mc', 'u', 'theta', 'theta_dot', 'wheel_angle', 'wheel_rate',
                                    'friction', 'true_theta', 'true_theta_dot', 'true_wheel_angle',
                                    'true_wheel_rate', 'torque', 'true_friction', 'disturbance')}
    switches, faults = [(0.0, ctrl.mode, ctrl.law, 'start')], []
    u_prev = 0.0
    for k in range(n):
        _, pc, mc = core.sample()
        s = core.plant.state
        e = est.step(pc, mc, u_prev)
        u, st = ctrl.update(k * h, k, e.theta, e.theta_dot, e.wheel_angle, e.wheel_rate, e.friction)
        if st.event is not None:
            switches.append((k * h, st.mode, st.law, st.reason))
        if st.fault:
            faults.append((k * h, st.fault))
        for key, v in (('pc', pc), ('mc', mc), ('u', u), ('theta', e.theta), ('theta_dot', e.theta_dot),
                       ('wheel_angle', e.wheel_angle), ('wheel_rate', e.wheel_rate), ('friction', e.friction),
                       ('true_theta', s.theta), ('true_theta_dot', s.theta_dot),
                       ('true_wheel_angle', s.wheel_angle), ('true_wheel_rate', s.wheel_rate),
                       ('torque', s.torque), ('true_friction', s.friction),
                       ('disturbance', core.plant.disturbance)):
            rec[key][k] = v
        core.command(k, u)
        u_prev = max(-rig.u_max, min(rig.u_max, core.advance()))   # as the estimator node clamps
    truth = {k: rec.pop(k) for k in list(rec) if k.startswith('true_') or k in ('torque', 'disturbance')}
    return RunData(h=h, t=np.arange(n) * h, truth=truth, switches=switches, faults=faults, **rec)
