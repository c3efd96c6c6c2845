"""The configuration of one run, resolved as the nodes resolve their parameters (pure).

``./rwpend up --lockstep`` gives every node the rig YAML and ``stack.yaml``, then its overrides;
each node builds its part from them: the simulator a :class:`rwpend_sim.sim_core.SimCore` of the
plant's truth (``sim.rig.*``) with its command timeout and initial state, the estimator
``EstimatorConfig.from_values`` for the model rig, the controller its gains -- the ones given,
the others designed from ``<group>.design.*`` (:func:`rwpend_control.supervisor.gains_from_design`)
-- checked by :func:`rwpend_control.supervisor.validate_config`. :func:`resolve` does the same
steps with the same functions, from the defaults of those files plus the run's values, into a
:class:`RunSetup`: plain data (picklable, sent to the workers) from which
:func:`rwpend_sweep.run.build_loop` builds the loop of :mod:`rwpend_loop.loop`.

Precedence, lowest first: rig.yaml and stack.yaml, a compared controller's values
(``--compare``), ``scenario.fixed``, the run's axis values.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace
from functools import lru_cache
from typing import Any, Mapping

from rwpend_control.parameters import DESIGN_DEFAULTS, DESIGN_GROUPS, DESIGNED, PARAM_FIELDS
from rwpend_control.supervisor import ControllerConfig, config_with, gains_from_design, validate_config
from rwpend_estimation.estimators import EstimatorConfig
from rwpend_model.rig import SAMPLE_PERIOD_LIMITS, Rig, load_rig, read_params_file

from .spec import INITIAL_KEYS, MAX_DELAY, SpecError, Study

#: the node name ./rwpend up --lockstep runs under (its controller id derives from it)
NAMESPACE = '/rwpend'


@dataclass(frozen=True)
class RunSetup:
    """Everything one run needs (plain data: picklable)."""

    truth: Rig                    # the simulated plant (sim.rig.*)
    model: Rig                    # what the estimator and the controller read
    estimator: EstimatorConfig
    controller: ControllerConfig
    mode: str
    duration: float
    initial: dict = field(default_factory=dict)
    taps: tuple = ()
    torques: tuple = ()
    noise_counts: float = 0.0
    delay: int = 0
    noise_seed: tuple = (0,)
    law: tuple | None = None      # (source, params JSON) of a law of one's own (mode law)
    sim: dict = field(default_factory=dict)   # command_timeout_samples, claim_timeout_samples, ...
    controller_id: int = 1


@dataclass(frozen=True)
class Defaults:
    """The parameters every node starts from (rig YAML + stack.yaml)."""

    rig: Rig
    sim: dict
    estimator: dict
    controller: dict


@lru_cache(maxsize=1)
def defaults() -> Defaults:
    """rig.yaml and stack.yaml as ./rwpend up gives them to the nodes."""
    from rwpend_bringup.stack import stack_file
    f = stack_file()
    sim = {'command_timeout_samples': 3, 'claim_timeout_samples': 500, 'lockstep_timeout': 0.5,
           'loop_dead_after': 2.0}
    sim.update({k: v for k, v in read_params_file(f, 'sim').items() if k in sim})
    est_names = {x.name for x in fields(EstimatorConfig)}
    est = {k: v for k, v in read_params_file(f, 'estimator').items() if k in est_names}
    ctrl = {k: v for k, v in read_params_file(f, 'controller').items()
            if k in PARAM_FIELDS or k in DESIGN_DEFAULTS}
    return Defaults(load_rig(), sim, est, ctrl)


def lockstep_controller_id(ns: str = NAMESPACE) -> int:
    """The controller id of ``./rwpend up --lockstep`` (rwpend_bringup.stack.lockstep_controller_id)."""
    from rwpend_bringup.stack import lockstep_controller_id as cid
    return cid(ns)


def controller_config(model: Rig, given: Mapping[str, Any]) -> ControllerConfig:
    """The controller node's configuration from its parameters ``given`` (node parameter names):
    gains not given are designed from the design parameters, then everything is validated
    (ValueError with the reason) -- the steps of ControllerNode.__init__."""
    base = ControllerConfig()
    values = {n: given.get(n, None if n in DESIGNED else getattr(base, PARAM_FIELDS[n]))
              for n in PARAM_FIELDS}
    designs = {n: given.get(n, d) for n, d in DESIGN_DEFAULTS.items()}
    for group, names in DESIGN_GROUPS.items():
        if any(values[n] is None for n in names):
            prefix = f'{group}.design.'
            spec = {k[len(prefix):]: v for k, v in designs.items() if k.startswith(prefix)}
            try:
                designed = gains_from_design(model, group, spec)
            except (ValueError, TypeError, KeyError, ArithmeticError) as exc:
                raise ValueError(f'{group} design: {exc}') from None
            for n in names:
                if values[n] is None:
                    values[n] = designed[n]
    cfg = config_with(base, values)
    errors = validate_config(cfg, model)
    if errors:
        raise ValueError('; '.join(errors))
    return cfg


def split(values: Mapping[str, Any]) -> dict[str, dict]:
    """Axis-name values -> {'initial': .., 'plant': .., 'estimator': .., 'controller': .., 'special': ..}."""
    out: dict[str, dict] = {'initial': {}, 'plant': {}, 'estimator': {}, 'controller': {}, 'special': {}}
    for name, v in values.items():
        head, _, rest = name.partition('.')
        if head in ('initial', 'plant', 'estimator', 'controller') and rest:
            out[head][rest] = v
        else:
            out['special'][name] = v
    return out


def resolve(study: Study, values: Mapping[str, Any], *, index: int = 0,
            controller: Mapping[str, Any] | None = None, law: tuple | None = None,
            dflt: Defaults | None = None) -> RunSetup:
    """The :class:`RunSetup` of a run with these axis values (``fixed`` of the scenario below
    them, a compared ``controller``'s parameters and ``law`` below those). ValueError with the
    reason when a value is refused (as the node would refuse it)."""
    d = dflt or defaults()
    sc = study.scenario
    parts = split({**sc.fixed, **values})
    special = parts['special']
    model = d.rig
    common = {}
    if 'sample_period' in special:
        h = _float('sample_period', special['sample_period'])
        lo, hi = SAMPLE_PERIOD_LIMITS
        if not lo <= h <= hi:
            raise ValueError(f'sample_period must be in [{lo:g}, {hi:g}] s, got {h:g}')
        common['sample_period'] = h
    if 'encoder.counts_per_rev' in special:
        n = special['encoder.counts_per_rev']
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f'encoder.counts_per_rev must be an integer >= 1, got {n!r}')
        common['counts_per_rev'] = n
    if common:
        model = model.replace(**common)
    try:
        truth = Rig.from_params({**{f.name: getattr(model, f.name) for f in fields(Rig)}, **parts['plant']})
    except ValueError as exc:
        raise ValueError(f'plant: {exc}') from None
    est_given = {**d.estimator, **parts['estimator']}
    try:
        est = EstimatorConfig.from_values(est_given, rig=model)
    except ValueError as exc:
        raise ValueError(f'estimator: {exc}') from None
    ctrl_given = {**d.controller, **(controller or {}), **parts['controller']}
    try:
        ctrl = controller_config(model, ctrl_given)
    except ValueError as exc:
        raise ValueError(f'controller: {exc}') from None
    initial = {k: 0.0 for k in INITIAL_KEYS}
    initial.update(sc.initial)
    initial.update({k: _float(f'initial.{k}', v) for k, v in parts['initial'].items()})
    noise = _float('sensor.noise_counts', special.get('sensor.noise_counts', 0.0))
    if noise < 0:
        raise ValueError(f'sensor.noise_counts must be >= 0, got {noise:g}')
    delay = special.get('command.delay_samples', 0)
    if isinstance(delay, bool) or not isinstance(delay, int) or not 0 <= delay <= MAX_DELAY:
        raise ValueError(f'command.delay_samples must be an integer in 0..{MAX_DELAY}, got {delay!r}')
    mode = 'law' if law is not None else sc.mode
    return RunSetup(truth=truth, model=model, estimator=est, controller=ctrl, mode=mode,
                    duration=sc.duration, initial=initial, taps=sc.taps, torques=sc.torques,
                    noise_counts=noise, delay=delay, noise_seed=tuple(study.noise_seed(index)), law=law,
                    sim=dict(d.sim), controller_id=lockstep_controller_id())


def _float(name: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ValueError(f'{name} must be a finite number, got {v!r}')
    return float(v)


def nominal(setup: RunSetup, name: str) -> float:
    """The value of axis ``name`` in a run without that axis (the base of a ``factor``)."""
    head, _, rest = name.partition('.')
    if head == 'initial':
        return setup.initial[rest]
    if head == 'plant':
        return float(getattr(setup.truth, rest))
    if head == 'estimator':
        v = getattr(setup.estimator, rest)
    elif head == 'controller':
        if rest in PARAM_FIELDS:
            v = getattr(setup.controller, PARAM_FIELDS[rest])
        else:
            v = DESIGN_DEFAULTS[rest]
    elif name == 'sample_period':
        v = setup.model.sample_period
    elif name == 'sensor.noise_counts':
        v = setup.noise_counts
    else:
        v = None
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ValueError(f'a factor needs a numeric nominal value, {name} is {v!r}')
    return float(v)


def prepare(study: Study, controller: Mapping[str, Any] | None = None, law: tuple | None = None,
            label: str = '') -> tuple[list[dict], list[RunSetup]]:
    """Every run's axis values (a ``factor`` axis: the value run, factor x nominal) and its
    :class:`RunSetup`, checked: SpecError naming the axis (or the run and its values) and the
    reason, before anything runs."""
    where = f' (controller {label})' if label else ''
    try:
        base = resolve(study, {}, controller=controller, law=law)
    except ValueError as exc:
        raise SpecError(f'scenario{where}: {exc}') from None
    factors = {}
    for ax in study.dist_axes:
        if ax.dist == 'factor':
            try:
                factors[ax.name] = nominal(base, ax.name)
            except ValueError as exc:
                raise SpecError(f'axes.{ax.name}: {exc}') from None
    # each grid value alone first: the error names the axis and the value
    for ax in study.grid_axes:
        for v in ax.values:
            try:
                resolve(study, {ax.name: v}, controller=controller, law=law)
            except ValueError as exc:
                raise SpecError(f'axes.{ax.name}: value {v!r} refused{where}: {exc}') from None
    setups, rows = [], []
    cache: dict = {}
    for i in range(study.runs):
        values = study.run_values(i)
        for name, f in factors.items():
            values[name] = f * values[name]
        key = repr(sorted(values.items()))
        try:
            s = cache.get(key)
            if s is None:
                s = resolve(study, values, index=i, controller=controller, law=law)
                cache[key] = s
            else:
                s = replace(s, noise_seed=tuple(study.noise_seed(i)))
        except ValueError as exc:
            shown = ', '.join(f'{k} = {v:.6g}' if isinstance(v, float) else f'{k} = {v!r}' for k, v in values.items())
            raise SpecError(f'run {i} ({shown}) refused{where}: {exc}') from None
        setups.append(s)
        rows.append(values)
    return rows, setups
