"""Is the plant where an identification step needs it?  Pure checks (no rclpy, no numpy needed).

The same functions judge the live state (the procedures of :mod:`rwpend_ident.procedures`, which
refuse to start a step, or stop it, by raising :class:`NotReady`; the controller then turns off and
reports the reason in ``controller/status``) and recorded data (the analysis of a bag).

Angles in rad; a window is the angles of the last ``still_s`` seconds, one per sample.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence


class NotReady(Exception):
    """The plant is not where the step needs it (pendulum not at rest, wheel spinning, saturation
    reached, the wheel did not break away ...): the reason, for the student."""


@dataclass(frozen=True)
class Rest:
    """Tolerances of 'at rest, hanging': over ``still_s`` s the pendulum angle and the rotor angle
    relative to the pendulum each move by at most ``tol`` rad (2 encoder counts by default), and
    the pendulum hangs within ``hang`` rad of 0 (the encoders are zeroed hanging at rest)."""

    still_s: float = 0.5       # long enough to see a count of swing and fit it (rwpend_ident.estimate)
    tol: float = 2 * 2 * math.pi / 4000
    hang: float = 0.05
    timeout: float = 5.0       # s to wait for it before refusing the step


#: rad of slack in the comparisons with ``Rest.tol``: counts times the count angle are rounded,
#: so a spread of exactly 2 counts came out above 2 count angles for half of the count values
#: (229..231 did: a rest the controller had accepted was refused in the recording)
ROUNDING = 1e-9


def rest_problem(theta: Sequence[float], rel: Sequence[float], rest: Rest) -> str | None:
    """Why the pendulum is not at rest hanging with the rotor still over this window (``theta``
    pendulum angles, ``rel`` rotor angles relative to the pendulum), or None."""
    if not theta:
        return 'no samples to judge the pendulum by'
    moved = max(theta) - min(theta)
    if moved > rest.tol + ROUNDING:
        return (f'pendulum not at rest: it moved {moved:.4f} rad within {rest.still_s:g} s (at most '
                f'{rest.tol:.4f}); hold it still and let go gently')
    mean = sum(theta) / len(theta)
    if abs(mean) > rest.hang:
        return (f'pendulum not hanging: theta = {mean:.3f} rad at rest (expected 0 +- {rest.hang:g}; the '
                'encoders must be zeroed with the pendulum hanging at rest)')
    spun = max(rel) - min(rel)
    if spun > rest.tol + ROUNDING:
        return (f'wheel spinning: the rotor turned {spun:.3f} rad relative to the pendulum within '
                f'{rest.still_s:g} s; wait until it stops')
    return None


def saturation_problem(gain: float, min_gain: float, limit_s: float, what: str) -> str | None:
    """'saturation reached' when the command has been at |u| = u_max for ``limit_s`` s and the
    wheel gained only ``gain`` rad/s in the direction of u over them, less than ``min_gain``
    (``what``: where, e.g. 'at a wheel speed of 400 rad/s'); None while it still accelerates."""
    if gain < min_gain:
        return (f'saturation reached {what}: |u| at its limit for {limit_s:g} s and the wheel gained '
                f'{gain:.1f} rad/s (less than {min_gain:g}); the friction needs more torque than the '
                f'amplifier gives -- lower the speeds')
    return None


#: the share of the commanded samples the plant must have held for a response to be the rig's
#: (:func:`delivery_problem`, :func:`late_commands_problem`)
HELD_SHARE = 0.8
#: ... and of the samples commanded at the limit (:func:`late_commands_problem`)
SATURATED_HELD_SHARE = 0.98


#: the least move of the pendulum, in encoder counts, that shows its encoder and the direction
#: of its move (:func:`direction_problem`); one count can be a flicker at a count's edge
PENDULUM_MOVE_COUNTS = 1.5


def delivery_problem(commanded: list, held: list, pendulum_counts: float | None = None) -> str | None:
    """Why the first pulse did not reach the motor, or None: ``commanded`` the controller's
    commands from the pulse's first sample on, ``held`` what the plant held over the same
    samples (the device's report on the rig; the held value may be the amplifier's quantized
    one). The pulse is the run of commands equal to the first; it reached the motor when the
    plant held it for at least 80 % of those samples. A PC that falls behind the sample rate
    sends its commands late, and the device holds none longer than its hold limit
    (rwpend_driver/PROTOCOL.md): the pulse then arrives in fragments, and the pendulum's small
    move is no sign of a wiring fault. ``pendulum_counts``: the pendulum's largest move during
    the response; under :data:`PENDULUM_MOVE_COUNTS` any sample of the pulse not held is one too
    many (on the book's rig a pulse of u = 3 for 50 ms moves the hanging pendulum by a few counts
    only: a fresh-clone run held 46 of 51 samples and saw 1 count)."""
    if not commanded:
        return None
    u0 = commanded[0]
    n = 0
    while n < len(commanded) and commanded[n] == u0:
        n += 1
    tol = 0.01 * abs(u0) + 0.01
    got = min(n, sum(1 for x in held[:n + 3] if abs(x - u0) <= tol))
    small = pendulum_counts is not None and abs(pendulum_counts) < PENDULUM_MOVE_COUNTS
    if got >= (n if small else HELD_SHARE * n):
        return None
    moved = (f', and the pendulum moved {abs(pendulum_counts):.0f} count(s), too little to tell from an '
             'encoder that is not connected' if small else '')
    return (f'the pulse of u = {u0:g} did not reach the motor whole: the plant held it for {got} of the '
            f'{n} samples commanded{moved} (this PC fell behind the sample rate and the commands came '
            'late); run it again with less load on this PC')


def late_commands_problem(commanded: list, held: list, tol: float = 0.03, u_max: float = 10.0) -> str | None:
    """Why a procedure's refusal judged a motor that did not get the commands, or None:
    ``commanded`` the controller's commands over the window before the refusal, ``held`` what
    the plant held over the same samples (NaN where the bag has no report; those samples are not
    counted). A procedure judges the rig by its response to the commands (the wheel did not speed
    up under a saturated command, the rotor did not break away); when the plant held the command
    for less than 80 % of the window, the PC fell behind the sample rate (the device holds no
    command longer than its hold limit, rwpend_driver/PROTOCOL.md) and the verdict says nothing
    about the rig; of the samples commanded at the limit ``u_max`` it must have held 98 %.
    ``tol``: control units, the amplifier's step (u_max/pwm_steps) and more."""
    pairs = [(c, h) for c, h in zip(commanded, held) if c == c and h == h]
    if len(pairs) < 10:
        return None
    def whole(c, h):
        return abs(c - h) <= tol + 0.01 * abs(c)
    got = sum(1 for c, h in pairs if whole(c, h))
    # a verdict on the saturated commands (the friction run's "saturation reached") judges the
    # rig at full torque: a few missing samples there already lower the wheel's top speed
    # (a fresh-clone run held 271 of 333 of them, and the wheel stopped at 397 of 400 rad/s)
    top = [(c, h) for c, h in pairs if abs(c) >= u_max - tol]
    got_top = sum(1 for c, h in top if whole(c, h))
    if got >= HELD_SHARE * len(pairs) and (len(top) < 10 or got_top >= SATURATED_HELD_SHARE * len(top)):
        return None
    what = (f'the commanded u in {got} of {len(pairs)} samples' if got < HELD_SHARE * len(pairs) else
            f'the saturated u (|u| = {u_max:g}) in {got_top} of {len(top)} samples')
    return (f'the commands did not reach the motor whole before the refusal: the plant held {what} (this PC '
            'fell behind the sample rate and the commands came late), so the verdict is not the rig\'s; '
            'run it again with less load on this PC')


def direction_problem(u0: float, d_pendulum: float, d_rotor: float, count: float) -> str | None:
    """Encoder and motor directions from the first torque pulse of sign ``u0``: by (2.15) the
    rotor turns with u (theta_r'' = b_r (u - F)) and the pendulum against it
    (theta'' = -b_p (u - F)).  ``d_pendulum``, ``d_rotor``: the largest moves (rad, signed) of the
    pendulum and of the rotor relative to the pendulum during the response; ``count``: one count."""
    s = 1.0 if u0 > 0 else -1.0
    rotor = s * d_rotor
    pend = s * d_pendulum
    if abs(d_rotor) < 5 * count:
        return (f'the rotor did not turn during a pulse of u = {u0:g} (moved {abs(d_rotor) / count:.0f} counts): '
                'is the amplifier on and the motor connected?')
    if abs(d_pendulum) < PENDULUM_MOVE_COUNTS * count:
        return (f'the pendulum encoder did not move during a pulse of u = {u0:g}: is it connected?')
    if rotor > 0 and pend < 0:
        return None
    if rotor < 0 and pend > 0:
        return ('the motor turns against u: with u > 0 the rotor went negative and the pendulum positive '
                '(the motor leads or the amplifier input are reversed)')
    if rotor < 0:
        return ('the motor encoder counts backwards: with u > 0 the rotor counts went down while the '
                'pendulum moved against u as it should (swap the motor encoder channels A/B)')
    return ('the pendulum encoder counts backwards: with u > 0 the rotor turned with u but the pendulum '
            'counts went up (by (2.15) the pendulum moves against u; swap its channels A/B)')
