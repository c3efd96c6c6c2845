"""The controller node's parameters (pure, no rclpy): name, type, description, bounds, allowed
values (:class:`rwpend_ros.paramspec.ParamSpec`), for ``ros2 param describe`` and the node's
declarations. Bounds are those :func:`rwpend_control.supervisor.validate_config` judges (for
the rig), so what describe shows is what a set is refused against; the gains of a design group
have no default: designed at start from ``<group>.design.*`` unless given.
"""
from __future__ import annotations

from rwpend_ros.sched import thread_priority_spec
from rwpend_ros.paramspec import ParamSpec

from .laws import FRICTION_MODES
from .safety import SATURATION_ACTIONS, WHEEL_SPEED_ACTIONS
from .supervisor import (DESIGN_DEFAULTS, DESIGN_GROUPS, MODES, PARAM_FIELDS, ControllerConfig,
                         param_limits)

_U = 'control units'
_GAIN = f'{_U} per '
_BALANCE = 'u = -kpp x - kdp theta\' - kpr (theta_r - ref) - kdr (theta_r\' - rate_ref)'

#: Description of each controller parameter (ControllerConfig field, by parameter name).
DESCRIPTIONS = {
    'balance.kpp': f'balance gain on x = theta - pi, {_GAIN}rad, in {_BALANCE} ((4.9), (4.13), E28)',
    'balance.kdp': f'balance gain on theta\', {_GAIN}rad/s (see balance.kpp)',
    'balance.kpr': f'balance gain on the wheel angle from where balance started, {_GAIN}rad (4.13); '
                   '0 = none (4.9)',
    'balance.kdr': f'balance gain on the wheel rate, {_GAIN}rad/s (see balance.kpp)',
    'balance.rate_ref': 'balance: wheel rate reference rate_ref (omega_ref of (4.9)), rad/s',
    'patch.kpp': f'catch (auto): patched stabilizer gain on x, {_GAIN}rad; kpp = omega_p kdp '
                 '(Section 6.3, E39)',
    'patch.kdp': f'catch (auto): patched stabilizer gain on theta\', {_GAIN}rad/s',
    'patch.kdr': f'catch (auto): patched stabilizer gain on the wheel rate, {_GAIN}rad/s',
    'swingup.c_e': 'energy swing-up u = c_e (E - 2) theta\' - c_v theta_r\' (6.1), (6.2); c_e = '
                   'k_u k_e b_p a (E34)',
    'swingup.c_v': 'energy swing-up: wheel-rate gain c_v = k_u k_v (E34)',
    'swingup.kick': f'swing-up from rest: the first push, {_U}',
    'wheel.kp': f'wheel_velocity PI (3.14)-(3.16): proportional gain, {_GAIN}rad/s',
    'wheel.ki': f'wheel_velocity PI: integral gain per sample (E15), {_GAIN}rad/s',
    'wheel.ref': 'wheel_velocity: wheel rate reference, rad/s',
    'wheel_angle.kpr': f'wheel_angle PD (3.18): angle gain, {_GAIN}rad',
    'wheel_angle.kdr': f'wheel_angle PD: rate gain, {_GAIN}rad/s',
    'wheel_angle.ref': 'wheel_angle: wheel angle reference, rad',
    'theta_s': 'auto: catch when |theta - pi| < theta_s (6.5), rad',
    'theta_0': 'auto: back to swing-up, balance: fell (mode off), when |theta - pi| > theta_0, rad',
    'catch_region': 'auto: catch only inside the region (6.6) as well',
    'friction_compensation': 'friction compensation (Section 3.8): the model (3.17) at the '
                             'estimated rotor speed, or the estimator\'s estimate',
    'friction_deadband': 'friction compensation model: 0 within this relative rotor speed, rad/s',
    'allow_wheel_drift': 'accept balance gains without wheel feedback (the PD (4.2): the wheel drifts, (4.6))',
    'state_timeout_samples': 'no new state for this many samples (+ h/2) -> u = 0, fault "stale state"',
    'wheel_speed_limit': 'motor speed (rad/s) above which the mode goes off (overspeed), below the '
                         'back-EMF cut-off v_max/k_m (2.13)',
    'wheel_speed_action': 'above wheel_speed_limit: brake the wheel, or u = 0',
    'max_saturation_time': 'balance saturated for longer than this (s) -> saturation_action',
    'saturation_action': 'what balance does after max_saturation_time saturated',
}

#: Description of each design parameter.
DESIGN_DESCRIPTIONS = {
    'balance.design.kind': 'balance design: pdd (4.11), pdpd (4.15), pd (4.3), patch (6.3)',
    'balance.design.omega0': 'balance design: omega0, rad/s or a multiple of omega_p ("1.5wp")',
    'balance.design.zeta': 'balance design: damping of the omega0 pole pair',
    'balance.design.alpha': 'balance design pdd: the real pole at -alpha omega0',
    'balance.design.omega2': 'balance design pdpd: the second pole pair, rad/s or "wp"',
    'balance.design.zeta2': 'balance design pdpd: damping of the second pole pair',
    'patch.design.omega0': 'patch design (6.3): omega0, rad/s or a multiple of omega_p',
    'patch.design.zeta': 'patch design: damping',
    'swingup.design.k_e': 'swing-up design: the book\'s k_e (Section 5.3.1, E34)',
    'swingup.design.k_v': 'swing-up design: the book\'s k_v',
    'swingup.design.k_u': 'swing-up design: the book\'s k_u',
    'wheel.design.omega0': 'wheel_velocity PI design (3.15)-(3.16): omega0, rad/s',
    'wheel.design.zeta': 'wheel_velocity PI design: damping',
    'wheel_angle.design.omega0': 'wheel_angle PD design (3.18): omega0, rad/s',
    'wheel_angle.design.zeta': 'wheel_angle PD design: damping',
}

_CHOICES = {'mode': MODES, 'friction_compensation': FRICTION_MODES,
            'wheel_speed_action': WHEEL_SPEED_ACTIONS, 'saturation_action': SATURATION_ACTIONS,
            'balance.design.kind': ('pdd', 'pdpd', 'pd', 'patch')}
#: Design parameters that take a frequency as text ("1.5wp") or a number.
FREQUENCY_TEXT = {'balance.design.omega0', 'balance.design.omega2', 'patch.design.omega0'}
#: The gains designed when not given.
DESIGNED = frozenset(p for names in DESIGN_GROUPS.values() for p in names)
STATE_QUEUE_DEPTH_MAX = 10000
STATUS_EVERY_MAX = 1_000_000


def controller_specs(rig, state_queue_depth: int) -> list[ParamSpec]:
    """Every parameter of the controller for ``rig``: ``mode``, ``status_every``,
    ``state_queue_depth`` and ``controller_id`` (read-only), the design parameters and every ControllerConfig field."""
    specs = [
        ParamSpec('mode', 'off', 'operating mode (kept in sync with ~/set_mode and the '
                  'controller\'s own switches)', choices=MODES),
        ParamSpec('status_every', 10, 'publish controller/status every N state samples (and on '
                  'every switch)', low=1, high=STATUS_EVERY_MAX),
        ParamSpec('state_queue_depth', state_queue_depth, 'depth of the state subscription: a '
                  'controller that fell behind acts on the newest of these and drops older states',
                  low=1, high=STATE_QUEUE_DEPTH_MAX, read_only=True),
        ParamSpec('controller_id', 0, 'the id this controller puts in every command (the plant obeys '
                  'one controller at a time: rwpend_ros.claim); 0 = a random id drawn at start '
                  '(./rwpend up --lockstep gives a fixed one, so that lockstep bags are the same '
                  'every run)', low=0, read_only=True, constraints='< 2^63'),
        thread_priority_spec(),
    ]
    for name, default in DESIGN_DEFAULTS.items():
        if name in FREQUENCY_TEXT:
            specs.append(ParamSpec(name, default, DESIGN_DESCRIPTIONS[name], numbers_as_text=True,
                                   constraints='> 0 rad/s'))
        elif name in _CHOICES:
            specs.append(ParamSpec(name, default, DESIGN_DESCRIPTIONS[name], choices=_CHOICES[name]))
        else:
            low_open = name != 'swingup.design.k_v'
            specs.append(ParamSpec(name, float(default), DESIGN_DESCRIPTIONS[name], low=0.0,
                                   low_open=low_open))
    limits = param_limits(rig)
    defaults = ControllerConfig()
    for pname, fname in PARAM_FIELDS.items():
        default = None if pname in DESIGNED else getattr(defaults, fname)
        low, high = limits.get(pname, (None, None))
        extra = {}
        if pname == 'wheel_speed_limit':
            low, high, extra = 1.0, rig.omega_max, {'high_open': True}
        elif pname == 'wheel.ref':
            extra = {'constraints': '|wheel.ref| < wheel_speed_limit'}
        elif pname == 'theta_0':
            extra = {'constraints': '>= theta_s'}
        elif pname in ('balance.kpp', 'patch.kpp'):
            extra = {'constraints': 'closed loop (4.8) stable'}
        specs.append(ParamSpec(pname, default, DESCRIPTIONS[pname], low=low, high=high,
                               choices=_CHOICES.get(pname, ()), kind='double' if default is None else '',
                               **extra))
    return specs
