"""A run of the lab without ROS: the stack's own loop (rwpend_loop.loop) in lockstep.

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
from rwpend_loop.loop import ControllerStage, EstimatorStage, Loop, run_lockstep
from rwpend_ros.gate import CommandGate
from rwpend_ros.claim import CommandClaim
from rwpend_ros.health import LoopHealth
from rwpend_sim.sim_core import SimCore, SimHardware

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
    the plant's truth when it differs from the rig the estimator and controller use). The loop
    is the stack's own (:class:`rwpend_loop.loop.Loop` in lockstep)."""
    core = sim_core(plant_rig or rig, dict(run.sim))
    est = make_estimator(None, rig, EstimatorConfig.from_values(dict(run.estimator), rig=rig))
    ctrl = controller(rig, run)
    h = rig.sample_period
    n = int(round((run.duration if duration is None else duration) / h))
    hw = SimHardware(core)
    loop = Loop(hw, CommandGate(hw, CommandClaim(500), LoopHealth(h)), EstimatorStage(est),
                ControllerStage(ctrl, 1), h)
    rec = {k: np.zeros(n) for k in ('pc', 'mc', 'u', 'theta', 'theta_dot', 'wheel_angle', 'wheel_rate',
                                    'friction', 'true_theta', 'true_theta_dot', 'true_wheel_angle',
                                    'true_wheel_rate', 'torque', 'true_friction', 'disturbance')}
    switches, faults = [(0.0, ctrl.mode, ctrl.law, 'start')], []

    def on_tick(tick) -> None:
        k, r, e, st = tick.reading.seq, tick.reading, tick.estimate, tick.status
        if st is not None and st.event is not None:
            switches.append((k * h, st.mode, st.law, st.reason))
        if st is not None and st.fault:
            faults.append((k * h, st.fault_code, st.fault))
        s = r.truth
        for key, v in (('pc', r.pendulum_counts), ('mc', r.motor_counts), ('u', tick.u or 0.0),
                       ('true_theta', s.theta), ('true_theta_dot', s.theta_dot),
                       ('true_wheel_angle', s.wheel_angle), ('true_wheel_rate', s.wheel_rate),
                       ('torque', s.torque), ('true_friction', s.friction), ('disturbance', s.disturbance)):
            rec[key][k] = v
        if e is not None:
            for key in ('theta', 'theta_dot', 'wheel_angle', 'wheel_rate', 'friction'):
                rec[key][k] = getattr(e, key)
    run_lockstep(loop, n, on_tick)
    truth = {k: rec.pop(k) for k in list(rec) if k.startswith('true_') or k in ('torque', 'disturbance')}
    return RunData(h=h, t=np.arange(n) * h, truth=truth, switches=switches, faults=faults, **rec)
