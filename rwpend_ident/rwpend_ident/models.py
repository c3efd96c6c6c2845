"""The identified quantities, the rig they make, and the model runs the fits compare with data.

Pure Python + numpy/scipy (no rclpy).  The model is the project's one plant model,
:class:`rwpend_model.plant.Plant` -- (2.15) with the friction (3.17), stiction, the current lag
and the amplifier's PWM steps -- built from a :class:`~rwpend_model.rig.Rig`, so what the fits
assume is what the simulator runs and what every node reads from the rig YAML.

The identification measures the model parameters of (2.15), not the masses: a = m g l / J,
b_p = k_u / J, b_r = k_u / J_r.  :func:`rig_from_model` turns them back into physical data.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from rwpend_model.plant import Plant
from rwpend_model.rig import Rig

#: What the identification determines (Rig fields and the derived a, b_p, b_r of (2.15)).
IDENTIFIED = ('a', 'b_p', 'b_r', 'friction_coulomb_pos', 'friction_viscous_pos', 'friction_coulomb_neg',
              'friction_viscous_neg', 'friction_breakaway', 'motor_time_constant',
              'pendulum_energy_time_constant')
#: Units of the identified quantities (for reports).
UNITS = {'a': '1/s^2', 'b_p': 'rad/s^2/unit', 'b_r': 'rad/s^2/unit', 'omega_p': 'rad/s', 'omega_p_stuck': 'rad/s',
         'friction_coulomb_pos': 'units', 'friction_viscous_pos': 'units/(rad/s)',
         'friction_coulomb_neg': 'units', 'friction_viscous_neg': 'units/(rad/s)', 'friction_breakaway': 'units',
         'motor_time_constant': 's', 'pendulum_energy_time_constant': 's', 'm_p': 'kg', 'j_p': 'kg m^2',
         'j_r': 'kg m^2'}
#: Physical data the identification writes (the rest of the rig file comes from the base rig).
WRITTEN = ('m_p', 'j_p', 'j_r') + IDENTIFIED[3:]


def model_values(rig: Rig) -> dict[str, float]:
    """The identified quantities of a rig (a, b_p, b_r computed by rwpend_model.rig)."""
    return {k: float(getattr(rig, k)) for k in IDENTIFIED}


def rig_from_model(base: Rig, values: Mapping[str, float], physical: bool = True) -> Rig:
    """The rig of ``base`` with the model parameters ``values`` (a, b_p, b_r and Rig fields).

    ``physical``: g, k_u, l_p, l_r and m_r are kept from ``base`` (a ruler, a scale and the motor
    data sheet give them) and m_p, J_p, J_r are solved from (2.3) and (2.15):
    J = k_u / b_p, J_r = k_u / b_r, m l = a J / g, m_p = (m l - m_r l_r) / l_p,
    J_p = J - m_p l_p^2 - m_r l_r^2; ValueError when m_p or J_p would not be positive.
    Otherwise a split that exists for any positive a, b_p, b_r (l_p = l_r = g / (2a),
    J_p = J / 2, m_p = m_r), for simulating the candidates of a fit."""
    v = dict(values)
    fields = {k: float(v.pop(k)) for k in list(v) if k not in ('a', 'b_p', 'b_r')}
    a, b_p, b_r = (float(v.get(k, getattr(base, k))) for k in ('a', 'b_p', 'b_r'))
    if min(a, b_p, b_r) <= 0 or not all(math.isfinite(x) for x in (a, b_p, b_r)):
        raise ValueError(f'a, b_p, b_r must be positive, got {a:.6g}, {b_p:.6g}, {b_r:.6g}')
    J, j_r = base.k_u / b_p, base.k_u / b_r
    ml = a * J / base.g
    if physical:
        m_p = (ml - base.m_r * base.l_r) / base.l_p
        j_p = J - m_p * base.l_p ** 2 - base.m_r * base.l_r ** 2
        if m_p <= 0 or j_p <= 0:
            raise ValueError(f'a = {a:.5g}, b_p = {b_p:.5g} cannot be split into physical data with l_p = '
                             f'{base.l_p:g} m, l_r = {base.l_r:g} m, m_r = {base.m_r:g} kg of the base rig: '
                             f'm_p = {m_p:.4g} kg, J_p = {j_p:.4g} kg m^2 (measure l_p, l_r and m_r of this '
                             'rig and put them in the base rig file)')
        return base.replace(m_p=m_p, j_p=j_p, j_r=j_r, **fields)
    length = base.g / (2 * a)
    mass = ml / length / 2
    return base.replace(m_p=mass, m_r=mass, l_p=length, l_r=length, j_p=J / 2, j_r=j_r, **fields)


def free_swing(t: np.ndarray, wp2: float, damping: float, theta0: float, theta_dot0: float) -> np.ndarray:
    """theta at the sample times ``t`` (uniform, from t[0]) of the free swing with the rotor stuck
    to the pendulum (Section 2.3): (J + J_r) theta'' = -m g l sin(theta) - J c_p theta', i.e.
    theta'' = -omega_p'^2 sin(theta) - c theta' with omega_p'^2 = m g l / (J + J_r) and
    c = c_p J / (J + J_r), the dynamics the plant model integrates while the rotor sticks."""
    return swing_state(t, wp2, damping, theta0, theta_dot0)[0]


def swing_state(t: np.ndarray, wp2: float, damping: float, theta0: float,
                theta_dot0: float) -> tuple[np.ndarray, np.ndarray]:
    """(theta, theta') of :func:`free_swing`.  Classical Runge-Kutta 4 on the sample period (error
    < 1e-8 rad over a minute at omega h < 0.01)."""
    n = len(t)
    h = float(t[1] - t[0]) if n > 1 else 0.0
    out, vel = np.empty(n), np.empty(n)
    x, v = float(theta0), float(theta_dot0)
    wp2, damping = float(wp2), float(damping)   # Python floats: numpy scalars are ~5x slower here
    sin = math.sin
    for k in range(n):
        out[k], vel[k] = x, v
        a1 = -wp2 * sin(x) - damping * v
        v2 = v + 0.5 * h * a1
        a2 = -wp2 * sin(x + 0.5 * h * v) - damping * v2
        v3 = v + 0.5 * h * a2
        a3 = -wp2 * sin(x + 0.5 * h * v2) - damping * v3
        v4 = v + h * a3
        a4 = -wp2 * sin(x + h * v3) - damping * v4
        x += h / 6.0 * (v + 2 * v2 + 2 * v3 + v4)
        v += h / 6.0 * (a1 + 2 * a2 + 2 * a3 + a4)
    return out, vel


def plant_response(rig: Rig, u: np.ndarray, theta0: float = 0.0, theta_dot0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(theta, theta_r - theta) at every sample of an open-loop run with the recorded commands
    ``u`` (held over each sample; NaN: none, u = 0), by the plant model, from the pendulum at
    ``theta0``, ``theta_dot0`` with the rotor stuck to it (at rest by default)."""
    plant = Plant(rig, theta=theta0, theta_dot=theta_dot0, wheel_angle=theta0, wheel_rate=theta_dot0)
    n = len(u)
    th, phi = np.empty(n), np.empty(n)
    step = plant.step
    for k in range(n):
        s = plant.state
        th[k] = s.theta
        phi[k] = s.wheel_angle - s.theta
        step(float(u[k]))
    return th, phi
