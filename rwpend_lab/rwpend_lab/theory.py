"""Theory computed from the rig model (no rclpy): sampled loops, friction equilibria, describing functions."""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg import expm


def friction(rig, w: float) -> float:
    """F(w) of (3.17) from the rig data (units)."""
    return rig.friction(w)


def wheel_steady_speed(rig, u: float) -> float:
    """Wheel speed on the bracket where u = F(w) (3.12, 3.17), u beyond the Coulomb level."""
    if u > 0:
        return (u - rig.friction_coulomb_pos) / rig.friction_viscous_pos
    return (u + rig.friction_coulomb_neg) / rig.friction_viscous_neg


def wheel_loop_step(rig, kpr: float, kdr: float, ki: float, ref: float, duration: float,
                    estimator: str = 'difference', T: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Step response of the sampled wheel loop on the bracket, linear (viscous friction only):
    plant theta_r'' = b_r (tau - v theta_r'), current lag T_e (2.12), ZOH at h; the speed from the
    (filtered) difference (3.2)/(3.3); u = kpr (ref - theta_r) + kdr (ref_w - w_hat) + I (PI of (3.14)
    with ki per sample when ki > 0: then ``ref`` is a speed and kpr must be 0).
    Returns (t, true speed) for a speed loop, (t, angle) for an angle loop."""
    h, te, br, v = rig.sample_period, rig.motor_time_constant, rig.b_r, rig.friction_viscous_pos
    A = np.array([[0.0, 1.0, 0.0], [0.0, -br * v, br], [0.0, 0.0, -1.0 / te]])
    B = np.array([0.0, 0.0, 1.0 / te])
    Md = expm(np.block([[A, B[:, None]], [np.zeros((1, 4))]]) * h)
    Ad, Bd = Md[:3, :3], Md[:3, 3]
    c = T / (T + h)
    x = np.zeros(3)
    prev, w_hat, integ = 0.0, 0.0, 0.0
    n = int(round(duration / h))
    out = np.zeros(n)
    angle_loop = kpr > 0
    for k in range(n):
        theta = x[0]
        w_hat = c * w_hat + (theta - prev) / (T + h)
        prev = theta
        if angle_loop:
            u = kpr * (ref - theta) - kdr * w_hat
        else:
            e = ref - w_hat
            integ += ki * e
            u = kdr * e + integ
        out[k] = x[0] if angle_loop else x[1]
        x = Ad @ x + Bd * u
    return np.arange(n) * h, out


def overshoot(y: np.ndarray, final: float) -> float:
    """Peak overshoot as a fraction of the final value."""
    return max(0.0, float(np.max(y)) / final - 1.0)


def damping_from_overshoot(os: float) -> float:
    """zeta of a second-order system with this overshoot (fraction)."""
    if os <= 0:
        return 1.0
    L = math.log(os)
    return -L / math.sqrt(math.pi ** 2 + L * L)
