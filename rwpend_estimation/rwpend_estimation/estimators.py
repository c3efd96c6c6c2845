"""State estimators of *The Reaction Wheel Pendulum* (Block, Astrom, Spong) behind one interface.

Pure Python (math in the per-sample path, numpy/scipy only at construction): no rclpy.

Every estimator turns one encoder sample per sampling period h into an :class:`Estimate`::

    est = make_estimator('nonlinear', rig, EstimatorConfig())
    e = est.step(pendulum_counts, motor_counts, u, seq)   # u: command held over the last interval

Angles (Sections 2.1, 3.1)
    theta = phi * Delta + theta_offset, theta_r = (phi + phi_r) * Delta      (2.1)-(2.2)
    Delta = 2 pi / counts_per_rev.  The raw counters are int32; consecutive samples are
    unwrapped modulo 2**32 and accumulated in Python integers, so multi-turn counting never
    wraps (hours at 800 rad/s are fine).  Counts are absolute (zero hanging at rest when the
    experiment started, EncoderCounts.msg); ``reset()`` re-zeros at the counts of the newest
    sample received (taken or not).
    ``theta_offset`` (rad) is the up/down calibration added to theta (pi if started upright).
    The published angles are the *measured* angles (exact to one count) for every estimator;
    the estimators differ in the velocities and the friction.

Velocities and friction (``EstimatorConfig.estimator``)
    'difference'  (3.2) on both axes: omega_k = (theta_k - theta_{k-1}) / h.
    'filtered'    (3.3) on both axes, ERRATA E08:
                  y_f(t) = T/(T+h) y_f(t-h) + h/(T+h) * Delta_theta/h.
    'observer2'   wheel: second-order observer (3.5)/(3.6), k1 = 2 zeta omega0, k2 = omega0^2,
                  with the friction input F of ``friction_source``; pendulum: filtered
                  difference (3.3).
    'observer3'   wheel: third-order observer with the friction state (3.9)-(3.11),
                  (3.10) k1 = (alpha + 2 zeta) omega0, k2 = (1 + 2 alpha zeta) omega0^2,
                  k3 = alpha omega0^3; x3 = -b_r F (ERRATA E12) so F_hat = -x3_hat / b_r;
                  pendulum: filtered difference (3.3).
    'nonlinear'   wheel: 'observer3'; pendulum: the nonlinear observer (7.1) with the sign of
                  ERRATA E42 for theta from hanging,
                  dx2/dt = -a sin y - b_p (u - F_hat) + k2 (y - x1_hat),
                  k1 = 2 pendulum_zeta pendulum_omega0, k2 = pendulum_omega0^2.
    'joint5'      the joint observer (7.2)-(7.3) of Section 7.1.2, states
                  (theta, theta'/omega_p, theta_r, theta_r'/omega_p, F), gains K by pole
                  placement (scipy.signal.place_poles, YT: reproduces the book's K' tables,
                  ERRATA E44) for the poles (s^2 + 2 zeta omega0 s + omega0^2)^2 (s + alpha omega0).
                  (7.2) is the upright linearization; to run over the whole circle the term
                  omega_p x1 of row 2 is replaced by the exact gravity at the measured angle plus
                  the same linear error term: -(a/omega_p) sin y + omega_p (x1_hat - y).  Near
                  upright this *is* (7.2)-(7.3); everywhere the error dynamics are exactly
                  A - K C, i.e. the designed poles.

Missing, refused and repeated samples (:mod:`rwpend_estimation.gaps` decides, by seq)
    A sample is plausible when no encoder moved faster than ``max_rate`` since the last sample
    taken, over the whole seq gap: |delta counts| <= gap max_rate h / Delta.
    Bridged gap (at most ``max_bridge`` missing samples): the recursion is stepped through the
    missing samples with the measured angles interpolated linearly between the two samples
    taken, and the command of the sample held for ``command_timeout_samples``, then 0 -- what
    the plant applied, since nobody answered the missing samples -- so the observers
    (3.5)/(3.9)/(7.1)/(7.3) and the filters (3.2)/(3.3) stay continuous.  Interpolation rather
    than prediction alone: both ends are measured, so the angles are right at the end of the
    gap whatever u really was.  Why ``max_bridge`` = 20 (measured with the plant model, nonlinear
    estimator, 31 gaps per case, p95 of |velocity error|): right after a bridged gap of 20
    samples the error is 0.14 rad/s on the pendulum and 0.8 rad/s on the wheel in a swing-up
    (0.04 and 0.3 balancing), against the unknown velocities of a re-synchronisation (15.5 and
    300 rad/s on that sample; 0.8 and 1.8 rad/s ten samples later); from about 30 samples on,
    the bridge's wheel error (2-20 rad/s) exceeds the re-synchronisation's ten samples later,
    because the interpolated path no longer resembles the motion.
    Re-synchronisation (a longer gap, a plant restart, refused samples that the next samples
    confirm, or MAX_REFUSED refused samples in a row): the angles follow the counts, which are
    absolute (the same count -> angle map as before; after a plant restart the map of the first
    sample: the plant counts from its zero again); the velocities are unknown (0) on that sample
    and come from the next sample's difference (3.2), from which the observers start; the
    friction state is re-initialised from the static model (3.17) at that relative speed
    (E46): the wheel has coasted while the plant held u at zero, so the old estimate would be
    stale, and the model is what the observer (3.9) converges to (S19).  Every
    re-synchronisation is counted (``Estimate.resyncs``, :class:`rwpend_estimation.gaps.GapStats`).
    The same sample again (same seq and counts) raises DuplicateSampleError, an implausible one
    CountJumpError (nothing changes but the counters); at most gaps.MAX_REFUSED samples in a row
    are refused, whatever the input.

Discretization: forward Euler at h, as the book does in (3.6), (3.11) and (7.1):
    x_hat(t_k) = x_hat(t_{k-1}) + h [f(x_hat(t_{k-1}), y(t_{k-1}), u) + K (y(t_{k-1}) - C x_hat(t_{k-1}))]
where u is the command held over [t_{k-1}, t_k) -- the latest command received when sample k
arrives.  The published velocity of sample k is x_hat(t_k).  ``EstimatorConfig.validate(rig)``
refuses gains for which this recursion is unstable.

Friction (``friction_source``), the F used as input by 'observer2' and by the pendulum part of
'nonlinear', and the published friction:
    'observer'  the estimator's friction state (observer3/nonlinear: -x3_hat/b_r, joint5: x5_hat);
                estimators without one ('difference', 'filtered', 'observer2') use the static
                model instead.
    'model'     static friction model (3.17) ``rig.friction(w_rel)`` at the previous estimate
                of w_rel = theta_r' - theta' (ERRATA E46).
    'none'      F = 0 (the book's second-order observer of Section 3.4, which shows the bias).
The friction states of 'observer3'/'joint5' are part of those observers whatever the source.

Models: (2.15) theta'' + a sin theta = -b_p (u - F), theta_r'' = b_r (u - F) (theta from
hanging, F in control units) -- the parameters come from a :class:`rwpend_model.rig.Rig`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any, Mapping

import numpy as np

from rwpend_model.rig import Rig

from .gaps import DUPLICATE, FIRST, REFUSE, RESYNC, GapStats, GapTracker

#: Estimator names accepted by :func:`make_estimator` and the ``estimator`` parameter.
ESTIMATORS = ('difference', 'filtered', 'observer2', 'observer3', 'nonlinear', 'joint5')
#: Values of ``friction_source``.
FRICTION_SOURCES = ('observer', 'model', 'none')
#: Upper bound of ``max_bridge`` (samples): a bridge costs one recursion step per sample.
MAX_BRIDGE = 1000
_NOT_FLOAT = ('estimator', 'friction_source', 'max_bridge', 'command_timeout_samples')



class CountJumpError(ValueError):
    """An encoder sample jumps further than ``max_rate`` allows: refused, the state is unchanged."""


class DuplicateSampleError(ValueError):
    """The sample taken last again (same seq and counts): ignored, the state is unchanged."""


@dataclass(frozen=True)
class Estimate:
    """State estimate for one encoder sample (rad, rad/s, control units; theta from hanging)."""

    theta: float
    theta_dot: float
    wheel_angle: float
    wheel_rate: float
    friction: float
    energy: float
    resyncs: int = 0        # re-synchronisations of the estimator so far (gaps.GapStats.resyncs)
    missed: int = 0         # samples without an estimate just before this one

    def __init__(self, theta: float, theta_dot: float, wheel_angle: float, wheel_rate: float,
                 friction: float, energy: float, resyncs: int = 0, missed: int = 0) -> None:
        # the generated __init__ of a frozen dataclass sets each field through object.__setattr__
        # (twice the time); one is made every sample
        d = self.__dict__
        d['theta'], d['theta_dot'], d['wheel_angle'], d['wheel_rate'] = theta, theta_dot, wheel_angle, wheel_rate
        d['friction'], d['energy'], d['resyncs'], d['missed'] = friction, energy, resyncs, missed


#: Bounds of the numeric settings of :class:`EstimatorConfig`: name -> (low, low inclusive,
#: high); high is inclusive.
LIMITS: dict[str, tuple[float, bool, float]] = {
    'T': (0.0, True, 10.0),
    'omega0': (0.0, False, 1e5),
    'zeta': (0.0, False, 10.0),
    'alpha': (0.0, False, 100.0),
    'pendulum_omega0': (0.0, False, 1e5),
    'pendulum_zeta': (0.0, False, 10.0),
    'theta_offset': (-4 * math.pi, True, 4 * math.pi),
    'max_rate': (0.0, False, 1e6),
}


@dataclass(frozen=True)
class EstimatorConfig:
    """Every setting of the estimators (ROS parameters of the ``estimator`` node, same names).

    estimator        one of ESTIMATORS
    T                time constant of the filtered difference (3.3), s (0 = plain difference)
    omega0, zeta     wheel observers (3.6)/(3.10) and joint observer (7.3): rad/s, -
    alpha            friction pole alpha*omega0 of (3.10) and (7.3)
    pendulum_omega0, pendulum_zeta   nonlinear pendulum observer (7.1)
    friction_source  one of FRICTION_SOURCES
    theta_offset     up/down calibration added to theta (rad), e.g. pi if started upright
    max_rate         samples implying a faster motion than this (rad/s) on either encoder, over
                     the seq gap since the last sample taken, are refused (CountJumpError);
                     2000 rad/s > V_max/k_m + pendulum speed.
    max_bridge       most missing samples bridged (module doc); a longer gap re-synchronises.
    command_timeout_samples   the plant's command timeout (samples; the simulator's and the
                     driver's parameter of that name): over a bridged gap the last command is
                     held this long, then 0, as the plant does (nobody answered the missing
                     samples).
    """

    estimator: str = 'nonlinear'
    T: float = 0.01
    omega0: float = 100.0
    zeta: float = 0.707
    alpha: float = 1.0
    pendulum_omega0: float = 100.0
    pendulum_zeta: float = 0.707
    friction_source: str = 'observer'
    theta_offset: float = 0.0
    max_rate: float = 2000.0
    max_bridge: int = 20
    command_timeout_samples: int = 3

    # ------------------------------------------------------------------ validation
    def validate(self, rig: Rig | None = None) -> list[str]:
        """Reasons why this configuration is unacceptable (empty when fine).

        With a rig, also checks that the forward-Euler observers are stable at h and that the
        joint observer's poles can be placed.
        """
        errors: list[str] = []
        if self.estimator not in ESTIMATORS:
            errors.append(f'estimator must be one of {", ".join(ESTIMATORS)}, got {self.estimator!r}')
        if self.friction_source not in FRICTION_SOURCES:
            errors.append(f'friction_source must be one of {", ".join(FRICTION_SOURCES)}, '
                          f'got {self.friction_source!r}')
        numeric_ok = True
        for name, (lo, lo_incl, hi) in LIMITS.items():
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                errors.append(f'{name} must be a number, got {v!r}')
                numeric_ok = False
            elif not math.isfinite(v):
                errors.append(f'{name} must be finite, got {v!r}')
                numeric_ok = False
            elif (v < lo if lo_incl else v <= lo) or v > hi:
                lb = '[' if lo_incl else '('
                errors.append(f'{name} must be in {lb}{lo:g}, {hi:g}], got {v!r}')
                numeric_ok = False
        for name, hi in (('max_bridge', MAX_BRIDGE), ('command_timeout_samples', MAX_BRIDGE)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= hi:
                errors.append(f'{name} must be an integer in [0, {hi}] (samples), got {v!r}')
        if rig is not None and numeric_ok and not errors:
            errors.extend(_stability_errors(self, rig))
        return errors

    def replace(self, **changes: Any) -> 'EstimatorConfig':
        """A copy with some settings changed (not validated: call validate())."""
        return replace(self, **changes)

    @classmethod
    def from_values(cls, values: Mapping[str, Any], base: 'EstimatorConfig | None' = None,
                    rig: Rig | None = None) -> 'EstimatorConfig':
        """``base`` (default: defaults) with ``values`` applied; ints become floats.

        Raises ValueError with every reason when a name is unknown or a value is invalid.
        """
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(values) - names)
        if unknown:
            raise ValueError('unknown estimator setting(s): ' + ', '.join(unknown))
        coerced = {}
        for k, v in values.items():
            if k not in _NOT_FLOAT and isinstance(v, int) and not isinstance(v, bool):
                v = float(v)
            coerced[k] = v
        cfg = replace(base or cls(), **coerced)
        errors = cfg.validate(rig)
        if errors:
            raise ValueError('; '.join(errors))
        return cfg


# ---------------------------------------------------------------------- gains (book formulas)
def filter_coefficients(T: float, h: float) -> tuple[float, float]:
    """First-order filtered difference (3.3), ERRATA E08: y_f = c y_f(t-h) + d (theta_k - theta_{k-1}).

    c = T/(T+h), d = 1/(T+h)  (= h/(T+h) * 1/h).  Ripple for one count: Delta/(T+h).
    """
    return T / (T + h), 1.0 / (T + h)


def observer2_gains(omega0: float, zeta: float) -> tuple[float, float]:
    """Second-order observer (3.5): k1 = 2 zeta omega0, k2 = omega0^2 (Section 3.4)."""
    return 2.0 * zeta * omega0, omega0 * omega0


def observer3_gains(omega0: float, zeta: float, alpha: float) -> tuple[float, float, float]:
    """Third-order observer (3.9), gains (3.10) for (s + alpha omega0)(s^2 + 2 zeta omega0 s + omega0^2)."""
    return ((alpha + 2.0 * zeta) * omega0, (1.0 + 2.0 * alpha * zeta) * omega0 ** 2,
            alpha * omega0 ** 3)


def joint5_matrices(rig: Rig) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, C) of (7.2): x = (theta - pi, theta'/omega_p, theta_r, theta_r'/omega_p, F).

    Rows 1-2 are the upright linearization; A(2,5) = +b_p/omega_p, A(4,5) = -b_r/omega_p (E44).
    """
    wp, bp, br = rig.omega_p, rig.b_p, rig.b_r
    A = np.array([[0.0, wp, 0.0, 0.0, 0.0],
                  [wp, 0.0, 0.0, 0.0, bp / wp],
                  [0.0, 0.0, 0.0, wp, 0.0],
                  [0.0, 0.0, 0.0, 0.0, -br / wp],
                  [0.0, 0.0, 0.0, 0.0, 0.0]])
    B = np.array([[0.0], [-bp / wp], [0.0], [br / wp], [0.0]])
    C = np.array([[1.0, 0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0, 0.0]])
    return A, B, C


def joint5_poles(omega0: float, zeta: float, alpha: float) -> np.ndarray:
    """Observer poles of Section 7.1.2: roots of (s^2 + 2 zeta omega0 s + omega0^2)^2 (s + alpha omega0)."""
    p = np.roots([1.0, 2.0 * zeta * omega0, omega0 ** 2])
    return np.concatenate([p, p, [-alpha * omega0]])


def joint5_gains(rig: Rig, omega0: float, zeta: float, alpha: float) -> np.ndarray:
    """Gain K (5x2) of the joint observer (7.3): ``K = place(A', C', P)'`` as in the book's listing.

    ``joint5_gains(...).T`` is the book's printed K'.  Raises ValueError if the poles cannot be
    placed (e.g. zeta >= 1 makes a real pole of multiplicity > 2 = rank C).
    """
    import warnings

    from scipy.signal import place_poles
    A, _, C = joint5_matrices(rig)
    poles = joint5_poles(omega0, zeta, alpha)
    try:
        with warnings.catch_warnings():
            # YT may stop before its robustness optimum; the poles are checked below
            warnings.simplefilter('ignore', UserWarning)
            res = place_poles(A.T, C.T, poles)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise ValueError(f'joint observer poles cannot be placed for omega0={omega0}, '
                         f'zeta={zeta}, alpha={alpha}: {exc}') from exc
    K = np.asarray(res.gain_matrix).T.copy()
    ok = bool(np.all(np.isfinite(K)))
    if ok:
        got = np.linalg.eigvals(A - K @ C)
        # nearest computed pole for every requested one (repeated poles are sensitive: 1e-4)
        ok = max(float(np.min(np.abs(got - p))) for p in poles) <= 1e-4 * max(1.0, omega0)
    if not ok:
        raise ValueError(f'joint observer poles cannot be placed accurately for omega0={omega0}, '
                         f'zeta={zeta}, alpha={alpha}')
    return K


def _spectral_radius(m: np.ndarray) -> float:
    return float(max(abs(np.linalg.eigvals(m))))


def _stability_errors(cfg: EstimatorConfig, rig: Rig) -> list[str]:
    """Forward-Euler stability of the observers the configured estimator runs."""
    h = rig.sample_period
    errors = []
    name = cfg.estimator
    if name in ('observer2',):
        k1, k2 = observer2_gains(cfg.omega0, cfg.zeta)
        m = np.eye(2) + h * np.array([[-k1, 1.0], [-k2, 0.0]])
        if _spectral_radius(m) >= 1.0:
            errors.append(f'observer2 with omega0={cfg.omega0}, zeta={cfg.zeta} is unstable '
                          f'when sampled at h={h} (forward Euler); lower omega0')
    if name in ('observer3', 'nonlinear'):
        k1, k2, k3 = observer3_gains(cfg.omega0, cfg.zeta, cfg.alpha)
        m = np.eye(3) + h * np.array([[-k1, 1.0, 0.0], [-k2, 0.0, 1.0], [-k3, 0.0, 0.0]])
        if _spectral_radius(m) >= 1.0:
            errors.append(f'observer3 with omega0={cfg.omega0}, zeta={cfg.zeta}, alpha={cfg.alpha} '
                          f'is unstable when sampled at h={h} (forward Euler); lower omega0')
    if name == 'nonlinear':
        k1, k2 = observer2_gains(cfg.pendulum_omega0, cfg.pendulum_zeta)
        m = np.eye(2) + h * np.array([[-k1, 1.0], [-k2, 0.0]])
        if _spectral_radius(m) >= 1.0:
            errors.append(f'pendulum observer with pendulum_omega0={cfg.pendulum_omega0}, '
                          f'pendulum_zeta={cfg.pendulum_zeta} is unstable when sampled at h={h}')
    if name == 'joint5':
        try:
            K = joint5_gains(rig, cfg.omega0, cfg.zeta, cfg.alpha)
        except ValueError as exc:
            return [str(exc)]
        A, _, C = joint5_matrices(rig)
        if _spectral_radius(np.eye(5) + h * (A - K @ C)) >= 1.0:
            errors.append(f'joint5 with omega0={cfg.omega0}, zeta={cfg.zeta}, alpha={cfg.alpha} '
                          f'is unstable when sampled at h={h}; lower omega0')
    return errors


# ---------------------------------------------------------------------- estimators
class Estimator:
    """Base class: encoder bookkeeping (2.1)-(2.2), gaps and re-synchronisation (module doc)
    and the common interface.

    Subclasses implement ``_start()`` (initialise dynamic states from the current angles,
    velocities and friction) and ``_update(y, yr, u) -> (theta_dot, wheel_rate, friction)``
    (one step of the recursion from the previous sample to a sample with angles y, yr).
    """

    name = ''

    def __init__(self, rig: Rig, config: EstimatorConfig | None = None) -> None:
        config = replace(config or EstimatorConfig(), estimator=self.name)
        errors = config.validate(rig)
        if errors:
            raise ValueError('invalid estimator configuration: ' + '; '.join(errors))
        self.rig = rig
        self.config = config
        self.h = rig.sample_period
        self._delta = rig.count_angle
        self._a, self._bp, self._br = rig.a, rig.b_p, rig.b_r
        self._friction_model = rig.friction
        self._source = config.friction_source
        self._track = GapTracker(config.max_rate * self.h / self._delta, config.max_bridge)
        self._np = 0                               # unwrapped pendulum counts since the origin
        self._nm = 0                               # unwrapped motor counts since the origin
        self._theta0 = config.theta_offset         # theta at the origin
        self._wheel0 = 0.0                         # theta_r at the origin
        self._zero_first = False
        self._rates_unknown = False                # velocities of the last sample unknown (3.2 next)
        self.last: Estimate | None = None
        # dynamic state common to all: last measured angles, published rates and friction
        self._y = 0.0
        self._yr = 0.0
        self._wd = 0.0
        self._wrd = 0.0
        self._f = 0.0

    # ------------------------------------------------------------------ interface
    @property
    def raw_counts(self) -> tuple[int, int] | None:
        """(pendulum_counts, motor_counts) of the last sample taken, as received (int32)."""
        ref = self._track.reference
        return None if ref is None else (ref[1], ref[2])

    @property
    def newest_sample(self) -> tuple[int | None, int, int] | None:
        """(seq, pendulum_counts, motor_counts) of the newest sample received, taken or not."""
        return self._track.newest

    @property
    def gap_stats(self) -> GapStats:
        """Samples taken, refused, missing, bridged; re-synchronisations (gaps.GapStats)."""
        return self._track.stats

    def step(self, pendulum_counts: int, motor_counts: int, u: float, seq: int | None = None) -> Estimate:
        """Estimate for one encoder sample; u = command held over the interval before it (and
        over the missing samples of a bridged gap); seq = the sample's counter (None: the next).

        Raises ValueError and changes nothing when the input is invalid; CountJumpError
        (refused) and DuplicateSampleError (ignored) change only the counters.
        """
        pc, mc = pendulum_counts, motor_counts
        if not (type(pc) is int and type(mc) is int and type(u) is float and type(seq) is int):
            pc, mc, u, seq = self._checked(pc, mc, u, seq)
        elif not (seq >= 0 and -math.inf < u < math.inf):
            pc, mc, u, seq = self._checked(pc, mc, u, seq)      # raises ValueError
        nxt = None if self._rates_unknown else self._track.take_next(seq, pc, mc)
        if nxt is None:
            return self._step_judged(pc, mc, u, seq)
        # the next sample, plausible, the rates known (every sample's path): what
        # _step_judged does with judge's verdict TAKE of gap 1
        self._np += nxt[0]
        self._nm += nxt[1]
        dl = self._delta
        y = self._theta0 + self._np * dl
        yr = self._wheel0 + (self._np + self._nm) * dl
        if self.config.command_timeout_samples < 1:
            u = 0.0                  # as _bridge: the plant held the command for 0 samples
        self._wd, self._wrd, self._f = self._update(y, yr, u)
        self._y, self._yr = y, yr
        est = Estimate(y, self._wd, yr, self._wrd, self._f,
                       1.0 - math.cos(y) + 0.5 * self._wd * self._wd / self._a,
                       self._track.stats.resyncs, 0)
        self.last = est
        return est

    def _step_judged(self, pc: int, mc: int, u: float, seq: int | None) -> Estimate:
        """:meth:`step` for checked inputs, whatever :meth:`GapTracker.judge` says of them."""
        kind, dp, dm, gap, missed, absolute, reason = self._track.judge(seq, pc, mc)
        if kind == REFUSE:
            raise CountJumpError(f'{reason} (max_rate = {self.config.max_rate:g} rad/s)')
        if kind == DUPLICATE:
            raise DuplicateSampleError(reason)
        if absolute:
            self._origin_at(pc, mc)
        else:
            self._np += dp
            self._nm += dm
        dl = self._delta
        y = self._theta0 + self._np * dl
        yr = self._wheel0 + (self._np + self._nm) * dl
        if kind == FIRST or kind == RESYNC:
            self._restart(y, yr)
        elif self._rates_unknown:
            self._rates_from_difference(y, yr, gap)
        else:
            if gap > 1:
                u = self._bridge(y, yr, u, gap)
            elif self.config.command_timeout_samples < 1:
                u = 0.0                  # as _bridge: the plant held the command for 0 samples
            self._wd, self._wrd, self._f = self._update(y, yr, u)
            self._y, self._yr = y, yr
        est = Estimate(y, self._wd, yr, self._wrd, self._f,
                       1.0 - math.cos(y) + 0.5 * self._wd * self._wd / self._a,
                       self._track.stats.resyncs, missed)
        self.last = est
        return est

    def reset(self) -> None:
        """Re-zero the encoders at the counts of the newest sample received: theta =
        theta_offset, theta_r = 0; the velocities come from the next sample (3.2), the friction
        from the model.  Counted as a re-synchronisation.  Before the first sample: the first
        sample is zero."""
        self._theta0 = self.config.theta_offset
        self._wheel0 = 0.0
        self._np = self._nm = 0
        if self._track.rebase('reset') is None:
            self._zero_first = True
            return
        self._restart(self._theta0, 0.0)
        self.last = Estimate(self._y, 0.0, 0.0, 0.0, 0.0, 1.0 - math.cos(self._y),
                             self._track.stats.resyncs, 0)

    def init_from(self, est: Estimate, pendulum_counts: int, motor_counts: int,
                  track: GapTracker | None = None, rates_known: bool = True) -> None:
        """Continue from ``est``, the estimate of the sample with these counts (no jump).

        The angles of the next samples continue from est.theta / est.wheel_angle; the
        velocities and friction states start at est's values (``rates_known`` False: est was
        a (re-)initialisation, the next sample's difference (3.2) gives them).  ``track``: the
        gap bookkeeping to continue (its reference must be that sample; default: a new one,
        seq unknown).
        """
        vals = (est.theta, est.theta_dot, est.wheel_angle, est.wheel_rate, est.friction)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in vals):
            raise ValueError(f'init_from needs a finite estimate, got {est!r}')
        if track is not None:
            self._track = track.with_limits(self._track.max_step, self._track.max_bridge)
        else:
            self._track.adopt(None, pendulum_counts, motor_counts)
        self._np = self._nm = 0
        self._theta0, self._wheel0 = float(est.theta), float(est.wheel_angle)
        self._y, self._yr = self._theta0, self._wheel0
        self._wd, self._wrd, self._f = float(est.theta_dot), float(est.wheel_rate), float(est.friction)
        self._zero_first = False
        self._rates_unknown = not rates_known
        self._start()
        self.last = Estimate(self._y, self._wd, self._yr, self._wrd, self._f,
                             self.rig.energy(self._y, self._wd), self._track.stats.resyncs, 0)

    # ------------------------------------------------------------------ samples
    @staticmethod
    def _checked(pc, mc, u, seq) -> tuple[int, int, float, int | None]:
        if (type(pc) is int and type(mc) is int and type(u) is float and math.isfinite(u)
                and (seq is None or type(seq) is int and seq >= 0)):
            return pc, mc, u, seq       # the loop's own types: what the conversions below return
        for nm, v in (('pendulum_counts', pc), ('motor_counts', mc)):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise ValueError(f'{nm} must be an integer, got {v!r}')
        if not isinstance(u, (int, float, np.floating)) or isinstance(u, bool) or not math.isfinite(u):
            raise ValueError(f'u must be a finite number, got {u!r}')
        if seq is not None and (isinstance(seq, bool) or not isinstance(seq, (int, np.integer)) or seq < 0):
            raise ValueError(f'seq must be an integer >= 0 or None, got {seq!r}')
        return int(pc), int(mc), float(u), None if seq is None else int(seq)

    def _origin_at(self, pc: int, mc: int) -> None:
        """Angles from the absolute counts (the first sample, a plant restart), or zero at this
        sample after a reset() that came before any sample."""
        self._theta0, self._wheel0 = self.config.theta_offset, 0.0
        if self._zero_first:
            self._np = self._nm = 0
            self._zero_first = False
        else:
            self._np, self._nm = pc, mc

    def _restart(self, y: float, yr: float) -> None:
        """(Re-)initialise at a sample whose velocities are unknown: 0 until the next sample."""
        self._y, self._yr = y, yr
        self._wd = self._wrd = self._f = 0.0
        self._start()
        self._rates_unknown = True

    def _rates_from_difference(self, y: float, yr: float, gap: int) -> None:
        """The sample after a (re-)initialisation: velocities by the difference (3.2) over the
        gap, friction from the model (3.17) at w_rel = theta_r' - theta' (E46); the
        observers start from there."""
        dt = gap * self.h
        self._wd, self._wrd = (y - self._y) / dt, (yr - self._yr) / dt
        self._f = 0.0 if self._source == 'none' else self._friction_model(self._wrd - self._wd)
        self._y, self._yr = y, yr
        self._start()
        self._rates_unknown = False

    def _bridge(self, y: float, yr: float, u: float, gap: int) -> float:
        """Step the recursion through the gap - 1 missing samples before (y, yr): angles
        interpolated linearly, u held for command_timeout_samples, then 0 as the plant does
        (module doc).  Returns the u held over the last interval (before the sample)."""
        y0, yr0 = self._y, self._yr
        hold = self.config.command_timeout_samples
        for j in range(1, gap):
            s = j / gap
            yj, yrj = y0 + s * (y - y0), yr0 + s * (yr - yr0)
            self._wd, self._wrd, self._f = self._update(yj, yrj, u if j <= hold else 0.0)
            self._y, self._yr = yj, yrj
        return u if gap <= hold else 0.0

    # ------------------------------------------------------------------ helpers
    def _model_friction(self) -> float:
        """Static model (3.17) at the previous estimate of w_rel = theta_r' - theta'."""
        return self._friction_model(self._wrd - self._wd)

    def _input_friction(self, own: float | None) -> float:
        """Friction per ``friction_source`` (own = the estimator's friction state, if any)."""
        s = self._source
        if s == 'none':
            return 0.0
        if s == 'observer' and own is not None:
            return own
        return self._model_friction()

    # ------------------------------------------------------------------ subclass hooks
    def _start(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _update(self, y: float, yr: float, u: float) -> tuple[float, float, float]:  # pragma: no cover
        raise NotImplementedError


class _FilteredPendulum:
    """Mixin: pendulum velocity by the filtered difference (3.3) (T = 0: difference (3.2))."""

    def _pend_init(self, T: float) -> None:
        self._pc, self._pd = filter_coefficients(T, self.h)

    def _pend_rate(self, y: float) -> float:
        return self._pc * self._wd + self._pd * (y - self._y)


class DifferenceEstimator(_FilteredPendulum, Estimator):
    """(3.2) on both axes: omega_k = (theta_k - theta_{k-1})/h."""

    name = 'difference'

    def __init__(self, rig: Rig, config: EstimatorConfig | None = None) -> None:
        super().__init__(rig, config)
        self._pend_init(0.0)

    def _start(self) -> None:
        pass

    def _update(self, y, yr, u):
        wd = (y - self._y) / self.h
        wrd = (yr - self._yr) / self.h
        f = 0.0 if self._source == 'none' else self._friction_model(wrd - wd)
        return wd, wrd, f


class FilteredEstimator(_FilteredPendulum, Estimator):
    """(3.3) on both axes, time constant T (ERRATA E08)."""

    name = 'filtered'

    def __init__(self, rig: Rig, config: EstimatorConfig | None = None) -> None:
        super().__init__(rig, config)
        self._pend_init(self.config.T)

    def _start(self) -> None:
        pass

    def _update(self, y, yr, u):
        wd = self._pend_rate(y)
        wrd = self._pc * self._wrd + self._pd * (yr - self._yr)
        f = 0.0 if self._source == 'none' else self._friction_model(wrd - wd)
        return wd, wrd, f


class Observer2Estimator(_FilteredPendulum, Estimator):
    """Wheel: second-order observer (3.6) with F per friction_source; pendulum: (3.3)."""

    name = 'observer2'

    def __init__(self, rig: Rig, config: EstimatorConfig | None = None) -> None:
        super().__init__(rig, config)
        self._pend_init(self.config.T)
        self.k1, self.k2 = observer2_gains(self.config.omega0, self.config.zeta)
        self._x1 = 0.0

    def _start(self) -> None:
        self._x1 = self._yr

    def _update(self, y, yr, u):
        h = self.h
        f = self._input_friction(None)
        e = self._yr - self._x1                      # y(t_{k-1}) - x1_hat(t_{k-1})
        x2 = self._wrd
        self._x1 += h * (x2 + self.k1 * e)
        x2 += h * (self._br * (u - f) + self.k2 * e)
        return self._pend_rate(y), x2, f


class Observer3Estimator(_FilteredPendulum, Estimator):
    """Wheel: third-order observer with friction state (3.11), x3 = -b_r F (E12); pendulum: (3.3)."""

    name = 'observer3'

    def __init__(self, rig: Rig, config: EstimatorConfig | None = None) -> None:
        super().__init__(rig, config)
        self._pend_init(self.config.T)
        c = self.config
        self.k1, self.k2, self.k3 = observer3_gains(c.omega0, c.zeta, c.alpha)
        self._x1 = 0.0
        self._x3 = 0.0

    def _start(self) -> None:
        self._x1 = self._yr
        self._x3 = -self._br * self._f

    def _wheel(self, u: float) -> tuple[float, float]:
        """One step of (3.11); returns (x2_hat(t_k), F_hat(t_k))."""
        h = self.h
        e = self._yr - self._x1
        x2, x3 = self._wrd, self._x3
        self._x1 += h * (x2 + self.k1 * e)
        x2 += h * (x3 + self._br * u + self.k2 * e)
        self._x3 = x3 + h * self.k3 * e
        return x2, -self._x3 / self._br

    def _update(self, y, yr, u):
        wrd, f_obs = self._wheel(u)
        wd = self._pend_rate(y)
        s = self._source
        f = f_obs if s == 'observer' else (self._friction_model(wrd - wd) if s == 'model' else 0.0)
        return wd, wrd, f


class NonlinearEstimator(Observer3Estimator):
    """Wheel: (3.11); pendulum: nonlinear observer (7.1) with ERRATA E42 (theta from hanging)."""

    name = 'nonlinear'

    def __init__(self, rig: Rig, config: EstimatorConfig | None = None) -> None:
        super().__init__(rig, config)
        self.kp1, self.kp2 = observer2_gains(self.config.pendulum_omega0, self.config.pendulum_zeta)
        self._p1 = 0.0

    def _start(self) -> None:
        super()._start()
        self._p1 = self._y

    def _update(self, y, yr, u):
        h = self.h
        s = self._source
        f_obs = -self._x3 / self._br
        f_hat = f_obs if s == 'observer' else self._input_friction(f_obs)   # F_hat(t_{k-1})
        yp = self._y
        e = yp - self._p1
        p2 = self._wd
        self._p1 += h * (p2 + self.kp1 * e)
        p2 += h * (-self._a * math.sin(yp) - self._bp * (u - f_hat) + self.kp2 * e)
        # (3.11): _wheel(u) written out (every sample's path)
        e = self._yr - self._x1
        wrd, x3 = self._wrd, self._x3
        self._x1 += h * (wrd + self.k1 * e)
        wrd += h * (x3 + self._br * u + self.k2 * e)
        self._x3 = x3 + h * self.k3 * e
        f_obs = -self._x3 / self._br
        if s == 'observer':
            f = f_obs
        elif s == 'model':
            f = self._friction_model(wrd - p2)
        else:
            f = 0.0
        return p2, wrd, f


class Joint5Estimator(Estimator):
    """Joint observer (7.2)-(7.3), Section 7.1.2, gravity at the measured angle (see module doc)."""

    name = 'joint5'

    def __init__(self, rig: Rig, config: EstimatorConfig | None = None) -> None:
        super().__init__(rig, config)
        c = self.config
        self.K = joint5_gains(rig, c.omega0, c.zeta, c.alpha)
        (self._k11, self._k12), (self._k21, self._k22), (self._k31, self._k32), \
            (self._k41, self._k42), (self._k51, self._k52) = [tuple(map(float, r)) for r in self.K]
        wp = rig.omega_p
        self._wp = wp
        self._a_wp = rig.a / wp
        self._bp_wp = rig.b_p / wp
        self._br_wp = rig.b_r / wp
        self._x = [0.0] * 5

    def _start(self) -> None:
        wp = self._wp
        self._x = [self._y, self._wd / wp, self._yr, self._wrd / wp, self._f]

    def _update(self, y, yr, u):
        h = self.h
        x1, x2, x3, x4, x5 = self._x
        y1, y3 = self._y, self._yr
        e1 = y1 - x1
        e3 = y3 - x3
        wp = self._wp
        n1 = x1 + h * (wp * x2 + self._k11 * e1 + self._k12 * e3)
        n2 = x2 + h * (-self._a_wp * math.sin(y1) - wp * e1 + self._bp_wp * (x5 - u)
                       + self._k21 * e1 + self._k22 * e3)
        n3 = x3 + h * (wp * x4 + self._k31 * e1 + self._k32 * e3)
        n4 = x4 + h * (self._br_wp * (u - x5) + self._k41 * e1 + self._k42 * e3)
        n5 = x5 + h * (self._k51 * e1 + self._k52 * e3)
        self._x = [n1, n2, n3, n4, n5]
        wd, wrd = wp * n2, wp * n4
        s = self._source
        f = n5 if s == 'observer' else (self._friction_model(wrd - wd) if s == 'model' else 0.0)
        return wd, wrd, f


_CLASSES = {c.name: c for c in (DifferenceEstimator, FilteredEstimator, Observer2Estimator,
                                Observer3Estimator, NonlinearEstimator, Joint5Estimator)}


def make_estimator(name: str | None, rig: Rig, config: EstimatorConfig | None = None) -> Estimator:
    """Build the estimator ``name`` (default: config.estimator). Raises ValueError with reasons."""
    config = config or EstimatorConfig()
    if name is not None:
        if name not in _CLASSES:
            raise ValueError(f'estimator must be one of {", ".join(ESTIMATORS)}, got {name!r}')
        config = replace(config, estimator=name)
    if config.estimator not in _CLASSES:
        raise ValueError('invalid estimator configuration: ' + '; '.join(config.validate()))
    return _CLASSES[config.estimator](rig, config)


def switch_estimator(old: Estimator, config: EstimatorConfig) -> Estimator:
    """A new estimator for ``config`` continuing from ``old`` without a jump.

    The angle continues from old's last estimate; a change of theta_offset shifts theta by the
    difference (a deliberate recalibration).  A pending reset carries over.
    """
    new = make_estimator(None, old.rig, config)
    if old.last is not None and old.raw_counts is not None:
        est = old.last
        shift = config.theta_offset - old.config.theta_offset
        if shift:
            th = est.theta + shift
            est = replace(est, theta=th, energy=old.rig.energy(th, est.theta_dot))
        new.init_from(est, *old.raw_counts, track=old._track, rates_known=not old._rates_unknown)
    elif old._zero_first:
        new.reset()
    return new
