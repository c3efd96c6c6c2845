"""A control law of one's own, run by the controller in place of the built-in laws (mode ``law``).

The lab's ``--law FILE.py`` (and its procedures) are loaded here.  Pure Python, no rclpy.

A law file defines either

* a function ``control(state, params) -> u``, or
* a class ``Law`` built once as ``Law(params)`` and called every sample, ``law(state) -> u``
  (a class keeps its own state between samples: an integrator, a filter, a schedule).

``state`` is a :class:`LawState` (the estimator's state of the sample, theta from hanging as in
(2.15), upright = pi; ``t`` = seconds since the law was switched on); ``params`` is a dict with the
rig's model parameters (``a``, ``b_p``, ``b_r``, ``omega_p``, ``h``, ``u_max``, ``k_u``) and the
values the caller gave (the lab passes the gains it designed from the book's pole
specifications).  The return value is u in control units; the controller saturates it to
|u| <= u_max and adds no friction compensation unless configured.

A law that raises, or returns something that is not a finite number, is *faulted*:
:meth:`UserLaw.__call__` raises :class:`LawError` with the reason (file and line of the error),
and the controller answers u = 0 and switches off with that reason -- the node never dies of it.

``source`` is a path to a ``.py`` file, or ``package.module:Name`` for a law shipped in a package
(the lab's procedures).
"""
from __future__ import annotations

import importlib
import importlib.util
import itertools
import json
import math
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

_COUNTER = itertools.count()


class LawError(Exception):
    """A user law cannot be loaded, or failed on a sample (the message says why and where)."""


@dataclass(frozen=True)
class LawState:
    """What a law sees every sample (rad, rad/s, control units, s)."""

    t: float
    theta: float
    theta_dot: float
    wheel_angle: float
    wheel_rate: float
    friction: float


def rig_params(rig) -> dict[str, float]:
    """The model parameters every law gets (computed from the rig, (2.15))."""
    return {'a': rig.a, 'b_p': rig.b_p, 'b_r': rig.b_r, 'omega_p': rig.omega_p,
            'h': rig.sample_period, 'u_max': rig.u_max, 'k_u': rig.k_u}


def parse_params(text: str) -> dict[str, Any]:
    """``law.params`` (a JSON object as text) -> dict; LawError with the reason."""
    try:
        value = json.loads(text or '{}')
    except json.JSONDecodeError as exc:
        raise LawError(f'law.params is not JSON: {exc}') from None
    if not isinstance(value, dict):
        raise LawError(f'law.params must be a JSON object, got {text!r:.80}')
    return value


def _where(exc: BaseException, path: str) -> str:
    """' (file.py, line N)' for the deepest frame of the law's own file, '' if none."""
    frames = [f for f in traceback.extract_tb(exc.__traceback__) if f.filename == path]
    if not frames:
        return ''
    return f' ({Path(path).name}, line {frames[-1].lineno})'


def _load_module(source: str):
    """(module, path of its file) for a file path or ``package.module:Name``."""
    if source.endswith('.py') or '/' in source:
        path = Path(source).expanduser().resolve()
        if not path.is_file():
            raise LawError(f'law file {source} does not exist')
        spec = importlib.util.spec_from_file_location(f'rwpend_user_law_{next(_COUNTER)}', path)
        if spec is None or spec.loader is None:
            raise LawError(f'law file {source} cannot be imported (not a Python file?)')
        module = importlib.util.module_from_spec(spec)
        try:
            spec.loader.exec_module(module)
        except Exception as exc:  # noqa: BLE001 - any error in the user's file is reported
            raise LawError(f'law file {source} does not load: {type(exc).__name__}: {exc}'
                           f'{_where(exc, str(path))}') from None
        return module, str(path)
    name = source.split(':', 1)[0]
    try:
        module = importlib.import_module(name)
    except Exception as exc:  # noqa: BLE001
        raise LawError(f'law module {name} does not load: {type(exc).__name__}: {exc}') from None
    return module, getattr(module, '__file__', '') or ''


class UserLaw:
    """A loaded law: ``law(state) -> u`` (a finite float) or LawError."""

    def __init__(self, source: str, params: Mapping[str, Any], rig=None) -> None:
        module, self.path = _load_module(source)
        self.source = source
        self.params = {**(rig_params(rig) if rig is not None else {}), **dict(params)}
        attr = source.split(':', 1)[1] if ':' in source and not source.endswith('.py') else None
        self.name = attr or ('Law' if hasattr(module, 'Law') else 'control')
        target = getattr(module, self.name, None)
        if target is None:
            raise LawError(f'{source} defines neither a class Law(params) nor a function '
                           'control(state, params)')
        if not callable(target):
            raise LawError(f'{source}: {self.name} is not callable')
        self._fn: Callable[[LawState], Any]
        if isinstance(target, type):
            try:
                obj = target(self.params)
            except Exception as exc:  # noqa: BLE001
                raise LawError(f'{source}: {self.name}(params) failed: {type(exc).__name__}: {exc}'
                               f'{_where(exc, self.path)}') from None
            if not callable(obj):
                raise LawError(f'{source}: a {self.name} object is not callable (define __call__(self, state))')
            self._fn = obj
        else:
            self._fn = lambda state, f=target, p=self.params: f(state, p)

    def __call__(self, state: LawState) -> float:
        try:
            u = self._fn(state)
        except Exception as exc:  # noqa: BLE001 - the user's code: every error is a fault
            raise LawError(f'{Path(self.path).name or self.source}: {type(exc).__name__}: {exc}'
                           f'{_where(exc, self.path)} at t = {state.t:.3f} s') from None
        v = None
        if not isinstance(u, (bool, str, bytes)):
            try:
                v = float(u)       # a numpy scalar is fine
            except (TypeError, ValueError):
                v = None
        if v is None or not math.isfinite(v):
            raise LawError(f'{Path(self.path).name or self.source}: returned {u!r:.60}, not a finite '
                           f'number, at t = {state.t:.3f} s')
        return v


def load_law(source: str, params: Mapping[str, Any] | str = '{}', rig=None) -> UserLaw:
    """Load a law (``params`` a dict or its JSON text); LawError with the reason."""
    if isinstance(params, str):
        params = parse_params(params)
    return UserLaw(source, params, rig)
