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


#: Fields that may be zero (switches: 0 = off).
_MAY_BE_ZERO = {'pwm_steps', 'pendulum_energy_time_constant', 'friction_coulomb_pos',
                'friction_viscous_pos', 'friction_coulomb_neg', 'friction_viscous_neg',
                'friction_breakaway', 'motor_time_constant'}
_INT_FIELDS = {'pwm_steps', 'counts_per_rev'}


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
        if name in _INT_FIELDS and float(value) != int(value):
            errors.append(f'rig.{name} must be an integer, got {value!r}')
        if name in _MAY_BE_ZERO:
            if value < 0:
                errors.append(f'rig.{name} must be >= 0, got {value!r}')
        elif value <= 0:
            errors.append(f'rig.{name} must be > 0, got {value!r}')
    if 'sample_period' in values and not errors:
        h = float(values['sample_period'])
        if not 1e-5 <= h <= 0.1:
            errors.append(f'rig.sample_period must be within [1e-5, 0.1] s, got {h!r}')
    return errors


def read_params_file(path: str | Path, node_name: str = '') -> dict[str, Any]:
    """Flattened parameters for ``node_name`` from a ROS 2 parameters YAML file.

    Merges the ``/**`` section and the section of the node (``name`` or ``/ns/name``),
    the node's values winning, as rcl does.  Keys are dotted (``rig.g``).
    Raises ValueError with the reason for a file that is not a ROS 2 params file.
    """
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
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
