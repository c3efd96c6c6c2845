"""Rig parameters of the Reaction Wheel Pendulum: the physical data and the model parameters.

The physical data (Section 2.6 of Block, Astrom & Spong) live in one ROS 2 parameters
file, ``rwpend_model/config/rig.yaml``, read by every node.  The parameters of the
normalized model (2.15),

    theta''   + a sin(theta) = -b_p (u - F)
    theta_r''               =  b_r (u - F)

are *computed* here from the physical data, never retyped:

    m = m_p + m_r,  m l = m_p l_p + m_r l_r,  J = J_p + m_p l_p^2 + m_r l_r^2   (2.3)
    a = m g l / J = omega_p^2,  b_p = k_u / J,  b_r = k_u / J_r                (2.15)
    omega_p' = sqrt(m g l / (J + J_r))   (rotor stuck to the pendulum, Section 2.3)

With the book's listing value g = 9.91 these give a = 78.42, b_p = 1.0805, b_r = 198.0,
omega_p = 8.856 (the printed values); the physical g = 9.81 gives a = 77.63 (ERRATA E01).

Pure Python: no rclpy import.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

import yaml

#: Prefix of the rig parameters in the ROS parameter namespace of every node.
PARAM_PREFIX = 'rig.'

#: The book's listing value of g (``systpar``); its printed numbers come from it (E01).
BOOK_G = 9.91


def default_rig_file() -> Path:
    """Path of the rig YAML shipped with the package."""
    return Path(str(resources.files('rwpend_model').joinpath('config/rig.yaml')))


@dataclass(frozen=True)
class Rig:
    """Physical data of one rig (SI units; torques of the amplifier in control units).

    Every field is a ROS parameter ``rig.<field>``.  Derived model parameters are
    properties, so they can never disagree with the data they come from.
    """

    g: float = 9.81
    m_p: float = 0.2164
    m_r: float = 0.0850
    l_p: float = 0.1173
    l_r: float = 0.1270
    j_p: float = 2.233e-4
    j_r: float = 2.495e-5
    k_m: float = 0.0274
    r_a: float = 12.1
    l_a: float = 0.00627
    i_max: float = 1.8
    v_max: float = 22.7
    k_u: float = 0.00494
    u_max: float = 10.0
    motor_time_constant: float = 0.0005
    pwm_steps: int = 500
    counts_per_rev: int = 4000
    sample_period: float = 0.001
    friction_coulomb_pos: float = 0.99
    friction_viscous_pos: float = 0.0116
    friction_coulomb_neg: float = 0.97
    friction_viscous_neg: float = 0.0117
    friction_breakaway: float = 1.0
    pendulum_energy_time_constant: float = 60.0

    def __post_init__(self) -> None:
        errors = validate_rig_values({f.name: getattr(self, f.name) for f in fields(self)})
        if errors:
            raise ValueError('invalid rig parameters: ' + '; '.join(errors))

    # ---- derived quantities (2.3), (2.15) -------------------------------------------
    @property
    def m(self) -> float:
        """Combined mass m = m_p + m_r (kg), (2.3)."""
        return self.m_p + self.m_r

    @property
    def l(self) -> float:  # noqa: E743 - the book's name
        """Distance pivot to the combined centre of mass (m), m l = m_p l_p + m_r l_r (2.3)."""
        return (self.m_p * self.l_p + self.m_r * self.l_r) / self.m

    @property
    def J(self) -> float:  # noqa: N802 - the book's name
        """Pendulum inertia about the pivot, J = J_p + m_p l_p^2 + m_r l_r^2 (2.3)."""
        return self.j_p + self.m_p * self.l_p ** 2 + self.m_r * self.l_r ** 2

    @property
    def mgl(self) -> float:
        """Gravity torque amplitude m g l (Nm)."""
        return self.m * self.g * self.l

    @property
    def a(self) -> float:
        """a = m g l / J = omega_p^2 (1/s^2), (2.15)."""
        return self.mgl / self.J

    @property
    def b_p(self) -> float:
        """b_p = k_u / J (rad/s^2 per control unit), (2.15)."""
        return self.k_u / self.J

    @property
    def b_r(self) -> float:
        """b_r = k_u / J_r (rad/s^2 per control unit), (2.15)."""
        return self.k_u / self.j_r

    @property
    def omega_p(self) -> float:
        """Small-oscillation frequency of the pendulum, sqrt(m g l / J) (rad/s)."""
        return math.sqrt(self.a)

    @property
    def omega_p_stuck(self) -> float:
        """omega_p' = sqrt(m g l / (J + J_r)): rotor stuck to the pendulum (Section 2.3)."""
        return math.sqrt(self.mgl / (self.J + self.j_r))

    @property
    def omega_max(self) -> float:
        """Back-EMF cut-off speed V_max / k_m (rad/s) of the rotor relative to the pendulum (2.13)."""
        return self.v_max / self.k_m

    @property
    def count_angle(self) -> float:
        """One encoder count, 2 pi / counts_per_rev (rad) (Section 3.1: 0.00157 rad)."""
        return 2.0 * math.pi / self.counts_per_rev

    @property
    def pendulum_damping(self) -> float:
        """Viscous pendulum-axis damping d (1/s) in theta'' = ... - d theta'.

        For a lightly damped oscillator the energy decays as exp(-d t), so d is the
        inverse of the energy time constant of Fig. 2.3 (0 when that is 0 = off).
        """
        tau = self.pendulum_energy_time_constant
        return 0.0 if tau == 0 else 1.0 / tau

    def friction(self, w_rel: float) -> float:
        """Kinetic rotor friction F (control units) at relative speed w_rel = theta_r' - theta' (3.17).

        F = 0.99 + 0.0116 w for w > 0, F = -0.97 + 0.0117 w for w < 0, F = 0 at w = 0
        (at rest the friction is whatever holds the rotor, see the plant's stiction).
        """
        if w_rel > 0.0:
            return self.friction_coulomb_pos + self.friction_viscous_pos * w_rel
        if w_rel < 0.0:
            return -self.friction_coulomb_neg + self.friction_viscous_neg * w_rel
        return 0.0

    def energy(self, theta: float, theta_dot: float) -> float:
        """Scaled pendulum energy (6.2): E = 1 - cos(theta) + (theta'/omega_p)^2 / 2.

        0 hanging at rest, 2 upright at rest (ERRATA E36); E_phys = m g l * E.
        """
        return 1.0 - math.cos(theta) + 0.5 * (theta_dot / self.omega_p) ** 2

    def replace(self, **changes: Any) -> 'Rig':
        """A copy with some fields changed (validated)."""
        return dataclasses.replace(self, **changes)

    def as_params(self) -> dict[str, Any]:
        """The rig as ROS parameters ``{'rig.<field>': value}``."""
        return {PARAM_PREFIX + f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> 'Rig':
        """Build from ``{'rig.<field>': value}`` or ``{'<field>': value}``; unknown keys are an error."""
        names = {f.name: f for f in fields(cls)}
        values: dict[str, Any] = {}
        unknown = []
        for key, value in params.items():
            name = key[len(PARAM_PREFIX):] if key.startswith(PARAM_PREFIX) else key
            if name not in names:
                unknown.append(key)
                continue
            values[name] = value
        if unknown:
            raise ValueError('unknown rig parameter(s): ' + ', '.join(sorted(unknown)))
        errors = validate_rig_values(values)
        if errors:
            raise ValueError('invalid rig parameters: ' + '; '.join(errors))
        coerced = {}
        for name, value in values.items():
            coerced[name] = int(value) if names[name].type in ('int', int) else float(value)
        return cls(**coerced)


#: Fields that may be zero (switches: 0 = off); every other field must be > 0.
MAY_BE_ZERO = frozenset({'pwm_steps', 'pendulum_energy_time_constant', 'friction_coulomb_pos',
                         'friction_viscous_pos', 'friction_coulomb_neg', 'friction_viscous_neg',
                         'friction_breakaway', 'motor_time_constant'})
#: Integer fields.
INT_FIELDS = frozenset({'pwm_steps', 'counts_per_rev'})
#: Accepted sample periods h (s).
SAMPLE_PERIOD_LIMITS = (1e-5, 0.1)

#: What each field is, with its unit and where the book has it (the ``rig.*`` parameters'
#: descriptions; the values are in rig.yaml).
DESCRIPTIONS = {
    'g': 'gravity, m/s^2 (the book\'s systpar listing has 9.91, ERRATA E01)',
    'm_p': 'pendulum mass, kg (Section 2.6)',
    'm_r': 'rotor (wheel + motor rotor) mass, kg',
    'l_p': 'pivot to the pendulum\'s centre of mass, m',
    'l_r': 'pivot to the rotor\'s centre of mass, m',
    'j_p': 'pendulum inertia about its centre of mass, kg m^2',
    'j_r': 'rotor inertia about its axis, kg m^2',
    'k_m': 'motor torque constant = back-EMF constant, Nm/A (Section 2.4)',
    'r_a': 'armature resistance, ohm',
    'l_a': 'armature inductance, H',
    'i_max': 'amplifier current limit (u = u_max), A',
    'v_max': 'amplifier voltage, V: back-EMF cut-off at v_max/k_m (2.13, ERRATA E03)',
    'k_u': 'torque of one control unit, Nm (2.14, Fig. 2.4; ERRATA E02/E04)',
    'u_max': 'command limit, control units (|u| <= u_max)',
    'motor_time_constant': 'T_e of the current loop (first-order lag), s; 0 = none',
    'pwm_steps': 'PWM duty resolution per polarity (Section 2.5); 0 = no quantization',
    'counts_per_rev': 'encoder counts per revolution, both encoders (Section 3.1)',
    'sample_period': 'sampling period h, s',
    'friction_coulomb_pos': 'rotor friction (3.17) for w_rel > 0: Coulomb part, control units',
    'friction_viscous_pos': 'rotor friction (3.17) for w_rel > 0: viscous part, control units per rad/s',
    'friction_coulomb_neg': 'rotor friction (3.17) for w_rel < 0: Coulomb part, control units',
    'friction_viscous_neg': 'rotor friction (3.17) for w_rel < 0: viscous part, control units per rad/s',
    'friction_breakaway': 'torque across the rotor bearing below which the rotor sticks to the '
                          'pendulum, control units (Fig. 2.2, 2.4)',
    'pendulum_energy_time_constant': 'pendulum-axis friction: energy decay time constant, s '
                                     '(Fig. 2.3: about 1 min); 0 = no pendulum friction',
}


def validate_rig_values(values: Mapping[str, Any]) -> list[str]:
    """Reasons why these rig values are unacceptable (empty list when fine)."""
    errors = []
    for name, value in values.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            errors.append(f'rig.{name} must be a number, got {value!r}')
            continue
        if not math.isfinite(value):
            errors.append(f'rig.{name} must be finite, got {value!r}')
            continue
        if name in INT_FIELDS and float(value) != int(value):
            errors.append(f'rig.{name} must be an integer, got {value!r}')
        if name in MAY_BE_ZERO:
            if value < 0:
                errors.append(f'rig.{name} must be >= 0, got {value!r}')
        elif value <= 0:
            errors.append(f'rig.{name} must be > 0, got {value!r}')
    if 'sample_period' in values and not errors:
        h = float(values['sample_period'])
        lo, hi = SAMPLE_PERIOD_LIMITS
        if not lo <= h <= hi:
            errors.append(f'rig.sample_period must be within [{lo:g}, {hi:g}] s, got {h!r}')
    return errors


def load_yaml(text: str) -> Any:
    """``yaml.safe_load`` of ``text``, parsed by libyaml where PyYAML has it (about 8x faster:
    ``./rwpend up`` reads ten parameters files before it starts a process); a document libyaml
    refuses is parsed again by the pure-Python loader, whose error shows the line and a caret."""
    fast = getattr(yaml, 'CSafeLoader', None)
    if fast is not None:
        try:
            return yaml.load(text, Loader=fast)
        except yaml.YAMLError:
            pass
    return yaml.safe_load(text)


def read_params_file(path: str | Path, node_name: str = '') -> dict[str, Any]:
    """Flattened parameters for ``node_name`` from a ROS 2 parameters YAML file.

    Merges the ``/**`` section and the section of the node (``name`` or ``/ns/name``),
    the node's values winning, as rcl does.  Keys are dotted (``rig.g``).
    Raises ValueError with the reason for a file that is not a ROS 2 params file.
    """
    path = Path(path)
    try:
        doc = load_yaml(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f'cannot read parameters file {path}: {exc}') from exc
    if not isinstance(doc, dict):
        raise ValueError(f'{path}: not a ROS 2 parameters file (top level must be a mapping)')
    out: dict[str, Any] = {}
    short = node_name.rsplit('/', 1)[-1]
    sections = []
    for key, body in doc.items():
        if not isinstance(body, dict) or 'ros__parameters' not in body:
            raise ValueError(f'{path}: section {key!r} has no ros__parameters')
        k = str(key)
        if k in ('/**', '**'):
            sections.insert(0, body['ros__parameters'])
        elif node_name and (k == node_name or k.lstrip('/') == node_name.lstrip('/')
                            or k.endswith('/' + short) and k.startswith('/**') or k == short):
            sections.append(body['ros__parameters'])
    for params in sections:
        if not isinstance(params, dict):
            raise ValueError(f'{path}: ros__parameters must be a mapping')
        _flatten(params, '', out)
    return out


def _flatten(d: Mapping[str, Any], prefix: str, out: dict[str, Any]) -> None:
    for k, v in d.items():
        key = f'{prefix}{k}'
        if isinstance(v, dict):
            _flatten(v, key + '.', out)
        else:
            out[key] = v


def load_rig(path: str | Path | None = None, overrides: Mapping[str, Any] | None = None) -> Rig:
    """Rig from a params file (default: the shipped rig.yaml) plus ``rig.*`` overrides."""
    params = {k: v for k, v in read_params_file(path or default_rig_file()).items()
              if k.startswith(PARAM_PREFIX)}
    params.update(overrides or {})
    return Rig.from_params(params)


def load_rig_file(path: str | Path) -> Rig:
    """The rig of a complete rig YAML (``--rig FILE``, ``--plant-rig FILE``, an identified rig).

    Unlike :func:`load_rig` nothing is taken from the shipped file: every field of :class:`Rig`
    must be in the file's ``/**`` section under ``rig:``, and no other key may be there (a
    missing key would silently become the book's value in every node).  ValueError naming the
    file and the keys otherwise."""
    params = read_params_file(path)
    names = {f.name for f in fields(Rig)}
    given = {k[len(PARAM_PREFIX):] if k.startswith(PARAM_PREFIX) else k: v for k, v in params.items()}
    unknown = sorted(k for k in given if k not in names)
    missing = sorted(names - set(given))
    problems = []
    if unknown:
        problems.append('unknown key(s) ' + ', '.join(unknown))
    if missing:
        problems.append('missing rig key(s) ' + ', '.join(missing))
    if problems:
        raise ValueError(f'{path}: ' + '; '.join(problems) + ' (a rig file has every key of '
                         f'{default_rig_file()} under /**: ros__parameters: rig:)')
    try:
        return Rig.from_params(params)
    except ValueError as exc:
        raise ValueError(f'{path}: {exc}') from None


#: Derived model parameters compared by :func:`rig_differences` besides the data ((2.15)).
DERIVED = ('a', 'b_p', 'b_r', 'omega_p')


def rig_differences(model: Rig, truth: Rig, rel: float = 1e-9) -> list[tuple[str, float, float]]:
    """(name, model value, truth value) of every field -- and derived a, b_p, b_r, omega_p of
    (2.15) -- in which ``truth`` differs from ``model`` by more than ``rel`` (relative)."""
    out = []
    for name in [f.name for f in fields(Rig)] + list(DERIVED):
        m, t = float(getattr(model, name)), float(getattr(truth, name))
        if abs(t - m) > rel * max(abs(m), abs(t)):
            out.append((name, m, t))
    return out


def format_differences(diffs: list[tuple[str, float, float]]) -> str:
    """'m_p 0.2164 -> 0.24886 (+15.0 %), ...' ('' when there are none)."""
    parts = []
    for name, m, t in diffs:
        pct = f' ({100 * (t - m) / m:+.1f} %)' if m else ''
        parts.append(f'{name} {m:.6g} -> {t:.6g}{pct}')
    return ', '.join(parts)


def book_rig(**changes: Any) -> Rig:
    """The rig with the book's listing value g = 9.91, which reproduces its printed numbers (E01)."""
    return load_rig().replace(g=BOOK_G, **changes)


def typed_like(name: str, value, default):
    """``value`` of parameter ``name`` as the type of its ``default``: an integer where a float
    is expected is that float (YAML, ``--set`` and ``-p`` write 0 for 0.0), likewise in a list of
    floats; any other type is a ValueError naming the parameter."""
    def number(v) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool)
    kind = type(default)
    if kind is float and number(value):
        return float(value)
    if kind is int and isinstance(value, int) and not isinstance(value, bool):
        return value
    if kind in (bool, str) and isinstance(value, kind):
        return value
    if kind in (list, tuple) and not isinstance(value, (str, bytes, dict)):
        try:
            items = list(value)
        except TypeError:
            items = None
        if items is not None:
            if all(isinstance(d, float) for d in default) and all(number(v) for v in items):
                return [float(v) for v in items]
            if all(isinstance(v, type(d)) for v in items for d in default[:1]):
                return items
    expected = {float: 'a number', int: 'an integer', bool: 'true or false', str: 'a string'}.get(kind)
    if expected is None:
        expected = f'a list like {list(default)!r}'
    raise ValueError(f'{name} must be {expected}, got {value!r}')
