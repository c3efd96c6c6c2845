"""A study: one scenario x axes, read from a YAML file and checked before anything runs (pure).

    scenario:
      mode: auto                 # the controller's mode at start (rwpend_control.parameters.MODES)
      duration: 10               # simulated seconds of every run
      initial: {theta: 0.0}      # any of theta, theta_dot, wheel_angle, wheel_rate (rad, rad/s)
      taps: [{t: 6.0, dv: 0.5}]                      # scripted taps (theta_dot += dv at t)
      torques: [{t: 7.0, size: 2.0, duration: 0.1}]  # scripted torque pulses on the pendulum
      success: {tolerance: 0.1, last: 1.0}           # the default: |theta - pi| < 0.1 over the last second
      fixed: {controller.theta_s: 0.5}               # any axis name held at one value in every run
    axes:
      initial.theta: [2.8, 3.0, 3.2]                 # a list: a grid axis
      plant.m_p: {factor: [0.9, 1.1]}                # a distribution: Monte-Carlo (with samples)
      estimator.omega0: {uniform: [60, 140]}
      controller.balance.design.omega0: {normal: [13.0, 1.0]}
    samples: 1000                # runs per grid point (draws of the distributions)
    seed: 1

Runs: the grid is the product of the list axes (in the file's order); each grid point is run
``samples`` times; run i = g * samples + s. The distribution axes of run i are drawn from
``numpy.random.default_rng([seed, i])`` (in the file's order), the sensor noise of run i from
``default_rng([seed, i, 1])``: a run's values depend on the seed and its index only, never on
the number of workers.

Axis names (:data:`AXIS_HELP`): ``initial.*``; ``plant.<rig key>`` (the simulated plant's truth,
:class:`rwpend_model.rig.Rig`; the estimator and the controller keep the rig YAML);
``estimator.<setting>`` (:class:`rwpend_estimation.estimators.EstimatorConfig`);
``controller.<parameter>`` (gains such as ``balance.kpp``, design parameters such as
``balance.design.omega0``, ``theta_s`` ...: the controller node's parameters);
``encoder.counts_per_rev`` and ``sample_period`` (plant and model alike); ``sensor.noise_counts``
(standard deviation of a Gaussian noise added to both encoder counts, rounded to counts);
``command.delay_samples`` (the command of sample k drives [t_k+d, t_k+d+1)).

Every problem is a :class:`SpecError` naming the key and the reason; the CLI exits 2 on it.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

#: the keys of ``initial`` (the simulator's initial.* parameters)
INITIAL_KEYS = ('theta', 'theta_dot', 'wheel_angle', 'wheel_rate')
#: the distributions of a Monte-Carlo axis
DISTRIBUTIONS = ('uniform', 'normal', 'factor')
#: axes that are neither a rig key nor a node parameter (name -> (help, kind))
SPECIAL_AXES = {
    'encoder.counts_per_rev': ('encoder counts per revolution, both encoders of plant and model (Section 3.1)', int),
    'sample_period': ('sampling period h (s), plant, estimator and controller alike', float),
    'sensor.noise_counts': ('standard deviation (counts) of Gaussian noise added to both encoder readings', float),
    'command.delay_samples': ('samples by which the plant applies each command late (the estimator does not know)', int),
}
#: the longest command delay accepted (samples)
MAX_DELAY = 1000
#: top-level keys of a spec file
TOP_KEYS = ('scenario', 'axes', 'samples', 'seed', 'name')
SCENARIO_KEYS = ('mode', 'duration', 'initial', 'taps', 'torques', 'success', 'fixed')
SUCCESS_KEYS = ('tolerance', 'last', 'never_beyond')
#: the most runs of one study
MAX_RUNS = 10_000_000
#: the longest run (simulated s)
MAX_DURATION = 3600.0


class SpecError(ValueError):
    """A study that cannot run; the message names the key and says why."""


@dataclass(frozen=True)
class Axis:
    """One axis: a grid (``values``) or a distribution (``dist`` with its two numbers)."""

    name: str
    values: tuple = ()
    dist: str = ''
    a: float = 0.0
    b: float = 0.0

    @property
    def is_grid(self) -> bool:
        return not self.dist

    def describe(self) -> str:
        if self.is_grid:
            return f'{self.name}: {len(self.values)} values {list(self.values)[:6]}' + (' ...' if len(self.values) > 6 else '')
        return f'{self.name}: {self.dist} [{self.a:g}, {self.b:g}]'


@dataclass(frozen=True)
class Success:
    """Success of a run: |wrap(theta - pi)| < ``tolerance`` over the last ``last`` seconds and,
    with ``never_beyond``, never more than that from upright during the run (a catch that must
    hold, not fall and be swung up again)."""

    tolerance: float = 0.1
    last: float = 1.0
    never_beyond: float | None = None


@dataclass(frozen=True)
class Scenario:
    mode: str = 'auto'
    duration: float = 10.0
    initial: dict = field(default_factory=dict)
    taps: tuple = ()              # ((t, dv), ...)
    torques: tuple = ()           # ((t, size, duration), ...)
    success: Success = Success()
    fixed: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Study:
    name: str
    scenario: Scenario
    axes: tuple               # Axis, in the file's order
    samples: int = 1
    seed: int = 0

    @property
    def grid_axes(self) -> list[Axis]:
        return [a for a in self.axes if a.is_grid]

    @property
    def dist_axes(self) -> list[Axis]:
        return [a for a in self.axes if not a.is_grid]

    @property
    def grid_size(self) -> int:
        return math.prod(len(a.values) for a in self.grid_axes)

    @property
    def runs(self) -> int:
        return self.grid_size * self.samples

    def run_values(self, i: int) -> dict[str, Any]:
        """The axis values of run ``i`` (grid point i // samples; draws from (seed, i))."""
        if not 0 <= i < self.runs:
            raise IndexError(f'run {i} not in 0..{self.runs - 1}')
        out: dict[str, Any] = {}
        g = i // self.samples
        grid = self.grid_axes
        for ax in reversed(grid):            # the last axis varies fastest (itertools.product)
            g, j = divmod(g, len(ax.values))
            out[ax.name] = ax.values[j]
        out = {a.name: out[a.name] for a in grid}
        dists = self.dist_axes
        if dists:
            rng = np.random.default_rng([self.seed, i])
            for ax in dists:
                if ax.dist == 'normal':
                    out[ax.name] = float(rng.normal(ax.a, ax.b))
                else:   # uniform, factor: the factor is applied to the nominal value later
                    out[ax.name] = float(rng.uniform(ax.a, ax.b))
        return out

    def noise_seed(self, i: int) -> list[int]:
        return [self.seed, i, 1]


def _number(key: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise SpecError(f'{key}: must be a finite number, got {v!r}')
    return float(v)


def _mapping(key: str, v: Any, allowed: tuple) -> dict:
    if not isinstance(v, dict):
        raise SpecError(f'{key}: must be a mapping, got {type(v).__name__} {v!r:.60}')
    unknown = [k for k in v if k not in allowed]
    if unknown:
        raise SpecError(f'{key}: unknown key(s) {", ".join(map(str, unknown))} (known: {", ".join(allowed)})')
    return v


def axis_names_help() -> str:
    """What names an axis may have (for the error of an unknown one and ``--help``)."""
    return ('initial.{' + ','.join(INITIAL_KEYS) + '}, plant.<rig key>, estimator.<setting>, '
            'controller.<parameter>, ' + ', '.join(SPECIAL_AXES))


def check_axis_name(key: str, name: Any) -> None:
    """SpecError unless ``name`` is an axis this study can vary."""
    from dataclasses import fields as dc_fields
    from rwpend_estimation.estimators import EstimatorConfig
    from rwpend_model.rig import Rig
    from rwpend_control.parameters import DESIGN_DEFAULTS, PARAM_FIELDS
    if not isinstance(name, str):
        raise SpecError(f'{key}: an axis name must be text, got {name!r}')
    head, _, rest = name.partition('.')
    ok = False
    hint = ''
    if name in SPECIAL_AXES:
        ok = True
    elif head == 'initial':
        ok = rest in INITIAL_KEYS
        hint = f'initial.{{{",".join(INITIAL_KEYS)}}}'
    elif head == 'plant':
        names = [f.name for f in dc_fields(Rig)]
        ok = rest in names
        hint = 'a rig key: ' + ', '.join(names)
    elif head == 'estimator':
        names = [f.name for f in dc_fields(EstimatorConfig)]
        ok = rest in names
        hint = 'an estimator setting: ' + ', '.join(names)
    elif head == 'controller':
        ok = rest in PARAM_FIELDS or rest in DESIGN_DEFAULTS
        hint = 'a controller parameter (balance.kpp, balance.design.omega0, theta_s, ...)'
    if not ok:
        raise SpecError(f'{key}: unknown axis {name!r}' + (f' (expected {hint})' if hint else
                                                           f' (axes: {axis_names_help()})'))


def _axis(name: str, v: Any) -> Axis:
    key = f'axes.{name}'
    check_axis_name(key, name)
    if isinstance(v, list):
        if not v:
            raise SpecError(f'{key}: empty list of values')
        for x in v:
            if isinstance(x, (dict, list)) or x is None:
                raise SpecError(f'{key}: values must be numbers, text or booleans, got {x!r}')
        if len(set(map(repr, v))) != len(v):
            raise SpecError(f'{key}: a value is given twice')
        return Axis(name, values=tuple(v))
    if isinstance(v, dict):
        if len(v) != 1 or next(iter(v)) not in DISTRIBUTIONS:
            raise SpecError(f'{key}: a distribution is one of {{uniform: [lo, hi]}}, {{normal: [mean, sd]}}, '
                            f'{{factor: [lo, hi]}}, got {v!r}')
        dist, pair = next(iter(v.items()))
        if not isinstance(pair, list) or len(pair) != 2:
            raise SpecError(f'{key}.{dist}: two numbers [{"mean, sd" if dist == "normal" else "lo, hi"}], got {pair!r}')
        a, b = (_number(f'{key}.{dist}', x) for x in pair)
        if dist == 'normal':
            if not b > 0:
                raise SpecError(f'{key}.normal: the standard deviation must be > 0, got {b:g}')
        elif not a < b:
            raise SpecError(f'{key}.{dist}: empty range [{a:g}, {b:g}] (lo must be < hi)')
        if dist == 'factor' and a <= 0:
            raise SpecError(f'{key}.factor: the factors must be > 0, got [{a:g}, {b:g}]')
        if name in SPECIAL_AXES and SPECIAL_AXES[name][1] is int:
            raise SpecError(f'{key}: an integer axis takes a list of values, not a distribution')
        return Axis(name, dist=dist, a=a, b=b)
    raise SpecError(f'{key}: a list of values (grid) or a distribution mapping, got {v!r:.60}')


def _success(v: Any) -> Success:
    if v is None:
        return Success()
    m = _mapping('scenario.success', v, SUCCESS_KEYS)
    tol = _number('scenario.success.tolerance', m.get('tolerance', 0.1))
    last = _number('scenario.success.last', m.get('last', 1.0))
    nb = m.get('never_beyond')
    if not 0 < tol <= math.pi:
        raise SpecError(f'scenario.success.tolerance: must be in (0, pi] rad, got {tol:g}')
    if not last > 0:
        raise SpecError(f'scenario.success.last: must be > 0 s, got {last:g}')
    if nb is not None:
        nb = _number('scenario.success.never_beyond', nb)
        if not nb > 0:
            raise SpecError(f'scenario.success.never_beyond: must be > 0 rad, got {nb:g}')
    return Success(tol, last, nb)


def _events(key: str, v: Any, fields_: tuple) -> tuple:
    if v is None:
        return ()
    if not isinstance(v, list):
        raise SpecError(f'{key}: a list of {{{", ".join(fields_)}}}, got {v!r:.60}')
    out = []
    for j, item in enumerate(v):
        m = _mapping(f'{key}[{j}]', item, fields_)
        missing = [f for f in fields_ if f not in m]
        if missing:
            raise SpecError(f'{key}[{j}]: missing {", ".join(missing)}')
        out.append(tuple(_number(f'{key}[{j}].{f}', m[f]) for f in fields_))
    return tuple(out)


def _scenario(v: Any) -> Scenario:
    from rwpend_control.parameters import MODES
    m = _mapping('scenario', v if v is not None else {}, SCENARIO_KEYS)
    mode = m.get('mode', 'auto')
    if mode not in MODES:
        raise SpecError(f'scenario.mode: one of {", ".join(MODES)}, got {mode!r}')
    duration = _number('scenario.duration', m.get('duration', 10.0))
    if not 0 < duration <= MAX_DURATION:
        raise SpecError(f'scenario.duration: must be in (0, {MAX_DURATION:g}] s, got {duration:g}')
    initial = _mapping('scenario.initial', m.get('initial') or {}, INITIAL_KEYS)
    initial = {k: _number(f'scenario.initial.{k}', x) for k, x in initial.items()}
    taps = _events('scenario.taps', m.get('taps'), ('t', 'dv'))
    torques = _events('scenario.torques', m.get('torques'), ('t', 'size', 'duration'))
    success = _success(m.get('success'))
    if success.last > duration:
        raise SpecError(f'scenario.success.last: {success.last:g} s is longer than the run ({duration:g} s)')
    fixed = m.get('fixed') or {}
    if not isinstance(fixed, dict):
        raise SpecError(f'scenario.fixed: a mapping of axis names to values, got {fixed!r:.60}')
    for k, x in fixed.items():
        check_axis_name(f'scenario.fixed.{k}', k)
        if isinstance(x, (dict, list)) or x is None:
            raise SpecError(f'scenario.fixed.{k}: one value, got {x!r:.60}')
    return Scenario(mode, duration, initial, taps, torques, success, dict(fixed))


def study_from_dict(doc: Any, name: str = 'study') -> Study:
    """The study of a parsed spec; SpecError with the key and the reason. The values of every
    run are checked too (:func:`rwpend_sweep.build.prepare`)."""
    m = _mapping('spec', doc, TOP_KEYS)
    scenario = _scenario(m.get('scenario'))
    axes_doc = m.get('axes') or {}
    if not isinstance(axes_doc, dict):
        raise SpecError(f'axes: a mapping from axis names to values or distributions, got {axes_doc!r:.60}')
    axes = tuple(_axis(k, v) for k, v in axes_doc.items())
    both = [a.name for a in axes if a.name in scenario.fixed]
    if both:
        raise SpecError(f'axes.{both[0]}: also in scenario.fixed (one or the other)')
    has_dist = any(not a.is_grid for a in axes)
    samples = m.get('samples', None)
    if samples is None:
        if has_dist:
            raise SpecError('samples: a study with a distribution axis needs samples: N (runs per grid point)')
        samples = 1
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
        raise SpecError(f'samples: an integer >= 1, got {samples!r}')
    seed = m.get('seed', 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SpecError(f'seed: an integer >= 0, got {seed!r}')
    study = Study(str(m.get('name', name)), scenario, axes, samples, seed)
    if study.runs > MAX_RUNS:
        raise SpecError(f'axes: {study.runs} runs (more than {MAX_RUNS})')
    return study


def load_study(path: str | Path) -> Study:
    """The study of a spec file (SpecError naming the file on any problem)."""
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text(encoding='utf-8'))
    except OSError as exc:
        raise SpecError(f'{path}: cannot read: {exc.strerror or exc}') from None
    except yaml.YAMLError as exc:
        raise SpecError(f'{path}: not YAML: {exc}') from None
    try:
        return study_from_dict(doc, name=path.stem)
    except SpecError as exc:
        raise SpecError(f'{path}: {exc}') from None


def grid_points(study: Study) -> list[tuple]:
    """The grid's points in run order (itertools.product of the list axes)."""
    return list(itertools.product(*(a.values for a in study.grid_axes)))
