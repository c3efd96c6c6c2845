"""The controller node's parameters: one table, one row per parameter (pure, no rclpy).

Each row of :data:`PARAMS` (a :class:`Param`) gives a parameter's name, its type (that of its
default), its default, its range (a bound may be a function of the rig: e.g. of its sample
period) or allowed values, its description (with its unit) and whether it is read-only.
Everything else about the parameters is derived from the table:

* the node's declarations and the ParameterDescriptors ``ros2 param describe`` shows
  (:func:`controller_specs`: :class:`rwpend_ros.paramspec.ParamSpec` for the rig);
* the controller's configuration: :class:`rwpend_control.supervisor.ControllerConfig` has one
  field per row marked ``config`` (``balance.kpp`` -> ``balance_kpp``) with the row's default;
* the validation: :func:`type_refusal` and :func:`range_refusal` judge each value by its row
  (:func:`rwpend_control.supervisor.validate_config` adds what joins several rows: stability,
  hysteresis, the Routh conditions of the wheel loops);
* the design groups: a gain row marked ``designed`` has no default on the node -- it is designed
  at start from the design parameters ``<group>.design.*`` unless given (its default is the
  configuration's: the default rig's design) -- :data:`DESIGN_GROUPS`, :data:`DESIGN_DEFAULTS`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Callable, Union

from rwpend_ros.paramspec import ParamSpec, kind_of
from rwpend_ros.sched import thread_priority_spec

from .laws import FRICTION_MODES
from .safety import SATURATION_ACTIONS, WHEEL_SPEED_ACTIONS

#: The operating modes (parameter ``mode``, service ``~/set_mode``).
MODES = ('off', 'wheel_velocity', 'wheel_angle', 'balance', 'swingup', 'auto', 'law')
#: rad: the largest multi-turn angle a state may hold (beyond it the state is refused).
MAX_ANGLE = 1e7
STATE_QUEUE_DEPTH_MAX = 10000
STATUS_EVERY_MAX = 1_000_000

#: A bound of a range: a number, a function of the rig, or None (unbounded).
Bound = Union[float, Callable[[Any], float], None]


def lumped_lag(rig) -> float:
    """T_e (s): the motor's lag plus half a sample, the lumped lag of the wheel loops (Section 3.5)."""
    return rig.motor_time_constant + 0.5 * rig.sample_period


def wheel_rate_gain_max(rig) -> float:
    """The largest wheel-rate gain of the wheel loops: kdr b_r T_e <= 1 (E14: the sampled loop
    goes unstable a few times above)."""
    return 1.0 / (rig.b_r * lumped_lag(rig))


def _omega_max(rig) -> float:
    return rig.omega_max


def _minus_omega_max(rig) -> float:
    return -rig.omega_max


@dataclass(frozen=True)
class Param:
    """One parameter of the controller node (a row of :data:`PARAMS`).

    ``low``/``high``: the range (inclusive unless ``low_open``/``high_open``), each a number, a
    function of the rig or None; ``choices``: the allowed values of a string. ``config``: a field
    of ControllerConfig (:attr:`field`); ``designed``: a gain designed from its group's design
    parameters when not given. ``constraints``: what the range does not say (shown by ``ros2 param
    describe``); ``refusal``: the text of a value out of range when not the usual, a format of
    ``name``, ``value``, ``low``, ``high``.
    """

    name: str
    default: Any
    description: str
    low: Bound = None
    high: Bound = None
    choices: tuple[str, ...] = ()
    read_only: bool = False
    config: bool = False
    designed: bool = False
    low_open: bool = False
    high_open: bool = False
    numbers_as_text: bool = False
    constraints: str = ''
    refusal: str = ''

    @property
    def field(self) -> str:
        """The ControllerConfig field of the parameter: ``balance.kpp`` -> ``balance_kpp``."""
        return self.name.replace('.', '_')

    @property
    def kind(self) -> str:
        """The parameter's type, as ``ros2 param describe`` names it (that of its default)."""
        return kind_of(self.default)

    @property
    def group(self) -> str:
        """The design group of a designed gain or of a design parameter ('' for others)."""
        if self.designed or '.design.' in self.name:
            return self.name.split('.', 1)[0]
        return ''

    def bounds(self, rig) -> tuple[float | None, float | None]:
        """(low, high) for ``rig``."""
        return tuple(b(rig) if callable(b) else b for b in (self.low, self.high))

    def spec(self, rig) -> ParamSpec:
        """The node's declaration of the parameter for ``rig`` (a designed gain: no default)."""
        low, high = self.bounds(rig)
        default = None if self.designed else self.default
        return ParamSpec(self.name, default, self.description, low=low, high=high,
                         low_open=self.low_open, high_open=self.high_open, choices=self.choices,
                         numbers_as_text=self.numbers_as_text, read_only=self.read_only,
                         constraints=self.constraints, kind=self.kind)


_U = 'control units'
_GAIN = f'{_U} per '
_BALANCE = 'u = -kpp x - kdp theta\' - kpr (theta_r - ref) - kdr (theta_r\' - rate_ref)'
_STABLE = 'closed loop (4.8) stable'


def _gain(name: str, default: float, low: Bound, high: Bound, description: str, **kw: Any) -> Param:
    """A gain of the configuration, designed from its group's design parameters when not given."""
    return Param(name, default, description, low=low, high=high, config=True, designed=True, **kw)


def _setting(name: str, default: Any, description: str, low: Bound = None, high: Bound = None,
             **kw: Any) -> Param:
    """A field of the configuration given as it is (not designed)."""
    return Param(name, default, description, low=low, high=high, config=True, **kw)


def _design(name: str, default: Any, description: str, **kw: Any) -> Param:
    """A design parameter: a number > 0 unless said otherwise."""
    if isinstance(default, float):
        kw = {'low': 0.0, 'low_open': True, **kw}
    return Param(name, default, description, **kw)


def _frequency(name: str, default: str, description: str) -> Param:
    """A design frequency: rad/s, or a multiple of omega_p as text ("1.5wp")."""
    return Param(name, default, description, numbers_as_text=True, constraints='> 0 rad/s')


#: The controller node's parameters (module doc), in the order the node declares them.
PARAMS: tuple[Param, ...] = (
    Param('mode', 'off', 'operating mode (kept in sync with ~/set_mode and the controller\'s own '
          'switches)', choices=MODES),
    Param('status_every', 10, 'publish controller/status every N state samples (and on every '
          'switch)', low=1, high=STATUS_EVERY_MAX),
    # default: the node gives its QoS's depth (rwpend_ros.qos.QOS_CONTROL_LATEST, 5)
    Param('state_queue_depth', 5, 'depth of the state subscription: a controller that fell behind '
          'acts on the newest of these and drops older states', low=1, high=STATE_QUEUE_DEPTH_MAX,
          read_only=True),
    Param('controller_id', 0, 'the id this controller puts in every command (the plant obeys one '
          'controller at a time: rwpend_ros.claim); 0 = a random id drawn at start (./rwpend up '
          '--lockstep gives a fixed one, so that lockstep bags are the same every run)', low=0,
          read_only=True, constraints='< 2^63'),
    Param('law.file', '', "a law of one's own for mode 'law': a .py file or package.module:Name "
          '(rwpend_control.user_law); empty: none', read_only=True),
    # default '' (= no values), not '{}': ros2cli's `param load` reads a dumped '{}' as a YAML
    # mapping and cannot build the request (rclpy: "bad argument type")
    Param('law.params', '', 'a JSON object of the values the law gets (empty: none)', read_only=True),
    # the design parameters (Chapters 3-6 of the book; ERRATA E34 for the swing-up)
    _design('balance.design.kind', 'pdd', 'balance design: pdd (4.11), pdpd (4.15), pd (4.3), '
            'patch (6.3)', choices=('pdd', 'pdpd', 'pd', 'patch')),
    _frequency('balance.design.omega0', '1.5wp', 'balance design: omega0, rad/s or a multiple of '
               'omega_p ("1.5wp")'),
    _design('balance.design.zeta', 0.707, 'balance design: damping of the omega0 pole pair'),
    _design('balance.design.alpha', 0.2, 'balance design pdd: the real pole at -alpha omega0'),
    _frequency('balance.design.omega2', 'wp', 'balance design pdpd: the second pole pair, rad/s or "wp"'),
    _design('balance.design.zeta2', 1.0, 'balance design pdpd: damping of the second pole pair'),
    _frequency('patch.design.omega0', '1.5wp', 'patch design (6.3): omega0, rad/s or a multiple of omega_p'),
    _design('patch.design.zeta', 0.707, 'patch design: damping'),
    _design('swingup.design.k_e', 4000.0, 'swing-up design: the book\'s k_e (Section 5.3.1, E34)'),
    _design('swingup.design.k_v', 4.0, 'swing-up design: the book\'s k_v', low_open=False),
    _design('swingup.design.k_u', 0.4, 'swing-up design: the book\'s k_u'),
    _design('wheel.design.omega0', 20.0, 'wheel_velocity PI design (3.15)-(3.16): omega0, rad/s'),
    _design('wheel.design.zeta', 1.0, 'wheel_velocity PI design: damping'),
    _design('wheel_angle.design.omega0', 10.0, 'wheel_angle PD design (3.18): omega0, rad/s'),
    _design('wheel_angle.design.zeta', 0.707, 'wheel_angle PD design: damping'),
    # the configuration (ControllerConfig); the gains' defaults: the default rig's design
    _gain('balance.kpp', -282.0, -1e4, 1e4, f'balance gain on x = theta - pi, {_GAIN}rad, in '
          f'{_BALANCE} ((4.9), (4.13), E28)', constraints=_STABLE),
    _gain('balance.kdp', -25.4, -1e3, 1e3, f'balance gain on theta\', {_GAIN}rad/s (see balance.kpp)'),
    _gain('balance.kpr', 0.0, -100.0, 100.0, f'balance gain on the wheel angle from where balance '
          f'started, {_GAIN}rad (4.13); 0 = none (4.9)'),
    _gain('balance.kdr', -0.0302, -100.0, 100.0, f'balance gain on the wheel rate, {_GAIN}rad/s '
          '(see balance.kpp)'),
    _setting('balance.rate_ref', 0.0, 'balance: wheel rate reference rate_ref (omega_ref of (4.9)), '
             'rad/s', _minus_omega_max, _omega_max),
    _gain('patch.kpp', -389.8, -1e4, 1e4, f'catch (auto): patched stabilizer gain on x, {_GAIN}rad; '
          'kpp = omega_p kdp (Section 6.3, E39)', constraints=_STABLE),
    _gain('patch.kdp', -44.0, -1e3, 1e3, f'catch (auto): patched stabilizer gain on theta\', {_GAIN}rad/s'),
    _gain('patch.kdr', -0.1006, -100.0, 100.0, f'catch (auto): patched stabilizer gain on the wheel '
          f'rate, {_GAIN}rad/s'),
    _gain('swingup.c_e', 1.356e5, 0.0, 1e8, 'energy swing-up u = c_e (E - 2) theta\' - c_v theta_r\' '
          '(6.1), (6.2); c_e = k_u k_e b_p a (E34)'),
    _gain('swingup.c_v', 1.6, 0.0, 100.0, 'energy swing-up: wheel-rate gain c_v = k_u k_v (E34)'),
    _setting('swingup.kick', 10.0, f'swing-up from rest: the first push, {_U}', 0.0, lambda rig: rig.u_max),
    _gain('wheel.kp', 0.2, 0.0, wheel_rate_gain_max, f'wheel_velocity PI (3.14)-(3.16): proportional '
          f'gain, {_GAIN}rad/s'),
    _gain('wheel.ki', 0.002, 0.0, 1.0, f'wheel_velocity PI: integral gain per sample (E15), {_GAIN}rad/s'),
    _setting('wheel.ref', 0.0, 'wheel_velocity: wheel rate reference, rad/s', lambda rig: -0.9 * rig.omega_max,
             lambda rig: 0.9 * rig.omega_max, constraints='|wheel.ref| < wheel_speed_limit'),
    _gain('wheel_angle.kpr', 0.5, 0.0, 100.0, f'wheel_angle PD (3.18): angle gain, {_GAIN}rad'),
    _gain('wheel_angle.kdr', 0.07, 0.0, wheel_rate_gain_max, f'wheel_angle PD: rate gain, {_GAIN}rad/s'),
    _setting('wheel_angle.ref', 0.0, 'wheel_angle: wheel angle reference, rad', -MAX_ANGLE, MAX_ANGLE),
    _setting('theta_s', 0.5, 'auto: catch when |theta - pi| < theta_s (6.5), rad', 1e-3, math.pi),
    _setting('theta_0', 0.8, 'auto: back to swing-up, balance: fell (mode off), when |theta - pi| > '
             'theta_0, rad', 1e-3, math.pi, constraints='>= theta_s'),
    _setting('catch_region', False, 'auto: catch only inside the region (6.6) as well'),
    _setting('friction_compensation', 'off', 'friction compensation (Section 3.8): the model (3.17) '
             'at the estimated rotor speed, or the estimator\'s estimate', choices=FRICTION_MODES),
    _setting('friction_deadband', 1.0, 'friction compensation model: 0 within this relative rotor '
             'speed, rad/s', 0.0, 100.0),
    _setting('allow_wheel_drift', False, 'accept balance gains without wheel feedback (the PD (4.2): '
             'the wheel drifts, (4.6))'),
    # safety (rwpend_control.safety)
    _setting('state_timeout_samples', 3, 'no new state for this many samples (+ h/2) -> u = 0, fault '
             '"stale state"', 1, 1000),
    # below the back-EMF cut-off omega_max = V_max/k_m (2.13), beyond which no braking torque
    # along the motion can be produced any more
    _setting('wheel_speed_limit', 750.0, 'motor speed (rad/s) above which the mode goes off '
             '(overspeed), below the back-EMF cut-off v_max/k_m (2.13)', 1.0, _omega_max, high_open=True,
             refusal='{name} = {value:g} rad/s must be in [{low:g}, {high:.1f}) (below the back-EMF '
                     'cut-off V_max/k_m, (2.13))'),
    _setting('wheel_speed_action', 'brake', 'above wheel_speed_limit: brake the wheel, or u = 0',
             choices=WHEEL_SPEED_ACTIONS),
    _setting('max_saturation_time', 0.5, 'balance saturated for longer than this (s) -> '
             'saturation_action', lambda rig: rig.sample_period, 60.0),
    _setting('saturation_action', 'off', 'what balance does after max_saturation_time saturated',
             choices=SATURATION_ACTIONS),
)

#: Each row by parameter name.
BY_NAME: dict[str, Param] = {p.name: p for p in PARAMS}
#: The rows of ControllerConfig's fields, in its order.
CONFIG_PARAMS: tuple[Param, ...] = tuple(p for p in PARAMS if p.config)
#: Node parameter name -> ControllerConfig field.
PARAM_FIELDS: dict[str, str] = {p.name: p.field for p in CONFIG_PARAMS}
#: Design parameter name -> its default.
DESIGN_DEFAULTS: dict[str, Any] = {p.name: p.default for p in PARAMS if '.design.' in p.name}
#: Design group -> the gain parameters it designs.
DESIGN_GROUPS: dict[str, tuple[str, ...]] = {
    g: tuple(p.name for p in PARAMS if p.designed and p.group == g)
    for g in dict.fromkeys(p.group for p in PARAMS if p.designed)}
#: The gains designed when not given.
DESIGNED = frozenset(p.name for p in PARAMS if p.designed)


def design_group(name: str) -> str | None:
    """The design group a design parameter belongs to (``balance.design.zeta`` -> ``balance``)."""
    return BY_NAME[name].group if name in DESIGN_DEFAULTS else None


def controller_specs(rig, state_queue_depth: int) -> list[ParamSpec]:
    """Every parameter of the controller for ``rig`` (the rows of :data:`PARAMS`, the depth of the
    state subscription ``state_queue_depth`` as its default) and ``thread_priority``."""
    specs = [p.spec(rig) for p in PARAMS]
    specs = [replace(s, default=state_queue_depth) if s.name == 'state_queue_depth' else s for s in specs]
    return specs + [thread_priority_spec()]


def type_refusal(p: Param, value: Any) -> str:
    """Why ``value`` is not of the type of row ``p`` (or not one of its choices); '' when it is."""
    name, kind = p.name, p.kind
    if kind == 'bool':
        return '' if isinstance(value, bool) else f'{name} must be a bool, got {value!r}'
    if kind == 'string':
        if not isinstance(value, str) or (p.choices and value not in p.choices):
            return f'{name} must be one of {", ".join(p.choices)}, got {value!r}'
        return ''
    if kind == 'integer':
        if isinstance(value, bool) or not isinstance(value, int):
            return f'{name} must be an integer, got {value!r}'
        return ''
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f'{name} must be a number, got {value!r}'
    if not math.isfinite(value):
        return f'{name} must be finite, got {float(value)!r}'
    return ''


def range_refusal(p: Param, value: Any, rig) -> str:
    """Why ``value`` (of the row's type) is outside the range of row ``p`` for ``rig``; '' when
    it is inside (and for a row that is no number)."""
    if p.kind not in ('double', 'integer'):
        return ''
    low, high = p.bounds(rig)
    low = -math.inf if low is None else low
    high = math.inf if high is None else high
    above = low < value if p.low_open else low <= value
    below = value < high if p.high_open else value <= high
    if above and below:
        return ''
    if p.refusal:
        return p.refusal.format(name=p.name, value=value, low=low, high=high)
    return f'{p.name} = {value:g} out of range [{low:g}, {high:g}]'
