"""What a node parameter is (pure, no rclpy): :class:`ParamSpec` -- its type, description, range
and allowed values -- and how a value that ROS 2 tools send is read as that type (:func:`coerce`).

``ros2 param set`` and ``ros2 param load`` turn text into a typed value with YAML 1.1 rules:
``3`` is an integer, ``off``/``on``/``yes``/``no`` are booleans, ``1e-05`` (no dot) is a string;
``ros2 param load`` even re-reads every value of the file from its ``str()``, so a dumped
``mode: 'off'`` comes back as the boolean false. :func:`coerce` takes what such a tool means and
nothing else:

* a double parameter takes an integer (``3`` -> ``3.0``) and a number YAML 1.1 leaves as text
  (``1e-05``, ``1e3``);
* a string parameter whose allowed values include ``off`` takes false as ``'off'`` (``on`` and
  true likewise); a string parameter that also names a number (``numbers_as_text``: a frequency
  ``'1.5wp'`` or ``20``) takes a number as its text;
* an array parameter takes an empty array of any type, and a double array takes integers.

Any other value of another type is refused with the reason (:class:`ValueError`). The value
itself (range, allowed values) is judged by :func:`check`.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

#: Parameter types, named as ``ros2 param describe`` prints them (with '_' for ' ').
KINDS = ('bool', 'integer', 'double', 'string', 'bool_array', 'integer_array', 'double_array',
         'string_array')

#: A number as text (what YAML 1.1 leaves a string: 1e-05, 1e3, 5E+2 ...); no nan / inf.
_NUMBER = re.compile(r'[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?')


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def kind_of(value: Any) -> str:
    """The parameter type of a default value (ValueError for one ROS parameters cannot hold)."""
    if isinstance(value, bool):
        return 'bool'
    if isinstance(value, int):
        return 'integer'
    if isinstance(value, float):
        return 'double'
    if isinstance(value, str):
        return 'string'
    if isinstance(value, (list, tuple)) and value:
        for kind in ('bool', 'integer', 'double', 'string'):
            if all(kind_of(v) == kind for v in value):
                return kind + '_array'
    raise ValueError(f'no ROS parameter type for {value!r}')


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of a node.

    ``default``: its value when none is given; its type is the parameter's (``kind`` names the
    type when there is no default, ``default=None``: e.g. a gain designed at start). Bounds:
    ``low``/``high`` (None: unbounded), inclusive unless ``low_open``/``high_open``; ``step`` of
    an integer range (0: any). ``choices``: the allowed values of a string parameter.
    ``constraints``: what the bounds and choices do not say (shown by ``ros2 param describe``).
    """

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    step: int = 0
    choices: tuple[str, ...] = ()
    numbers_as_text: bool = False
    read_only: bool = False
    constraints: str = ''
    kind: str = ''

    def __post_init__(self) -> None:
        kind = self.kind or kind_of(self.default)
        if kind not in KINDS:
            raise ValueError(f'{self.name}: unknown parameter type {kind!r}')
        object.__setattr__(self, 'kind', kind)
        if self.default is not None and kind_of(self.default) != kind:
            raise ValueError(f'{self.name}: default {self.default!r} is not of type {kind}')

    @property
    def range(self) -> tuple[float, float] | None:
        """(from, to) for the descriptor's FloatingPointRange / IntegerRange: both bounds given."""
        if self.low is None or self.high is None:
            return None
        return self.low, self.high

    def constraint_text(self) -> str:
        """The constraints ``ros2 param describe`` shows as 'Additional constraints': allowed
        values, open or one-sided bounds, and ``constraints``."""
        parts = []
        if self.choices:
            parts.append('one of: ' + ', '.join(self.choices))
        if self.low is not None and (self.low_open or self.high is None):
            parts.append(f'{">" if self.low_open else ">="} {self.low:g}')
        if self.high is not None and (self.high_open or self.low is None):
            parts.append(f'{"<" if self.high_open else "<="} {self.high:g}')
        if self.constraints:
            parts.append(self.constraints)
        return '; '.join(parts)


_EXPECTED = {'bool': 'true or false', 'integer': 'an integer', 'double': 'a number',
             'string': 'a string', 'bool_array': 'a list of true/false',
             'integer_array': 'a list of integers', 'double_array': 'a list of numbers',
             'string_array': 'a list of strings'}


def _number_text(v: int | float) -> str:
    return repr(float(v)) if isinstance(v, float) else str(v)


def _scalar(kind: str, v: Any) -> tuple[bool, Any]:
    """(taken, value) of ``v`` read as a scalar of ``kind`` by the tools' rules."""
    if kind == 'double':
        if _is_number(v):
            return True, float(v)
        if isinstance(v, str) and _NUMBER.fullmatch(v.strip()):
            return True, float(v)
    elif kind == 'integer':
        if isinstance(v, int) and not isinstance(v, bool):
            return True, v
    elif kind == 'bool':
        if isinstance(v, bool):
            return True, v
    elif isinstance(v, str):
        return True, v
    return False, None


def coerce(spec: ParamSpec, value: Any) -> Any:
    """``value`` as the type of ``spec`` by the rules of the module docstring; ValueError naming
    the parameter and what it takes for anything else (None -- no value -- included)."""
    kind = spec.kind
    if kind.endswith('_array'):
        if isinstance(value, (list, tuple)):
            items = list(value)
            out = []
            for v in items:
                ok, x = _scalar(kind[:-6], v)
                if not ok or (kind == 'double_array' and isinstance(v, str)):
                    break
                out.append(x)
            else:
                return out
    else:
        ok, x = _scalar(kind, value)
        if ok:
            return x
        if kind == 'string':
            if value is False and 'off' in spec.choices:
                return 'off'
            if value is True and 'on' in spec.choices:
                return 'on'
            if spec.numbers_as_text and _is_number(value):
                return _number_text(value)
    got = f'{value!r}'
    if isinstance(value, bool) and kind == 'string':
        got += ' (YAML 1.1 reads on/off/yes/no/true/false as booleans)'
    expected = _EXPECTED[kind]
    if kind == 'string' and spec.numbers_as_text:
        expected = 'a string or a number'
    raise ValueError(f'{spec.name} must be {expected}, got {got}')


def check(spec: ParamSpec, value: Any) -> str:
    """Why ``value`` (already of the spec's type) is not acceptable for ``spec`` ('' when it is):
    not one of ``choices``, not finite (a double), outside the bounds or off the step."""
    name = spec.name
    if spec.choices and value not in spec.choices:
        return f'{name} must be one of {", ".join(spec.choices)}, got {value!r}'
    if spec.kind == 'double' and not math.isfinite(value):
        return f'{name} must be finite, got {value!r}'
    if spec.kind not in ('double', 'integer'):
        return ''
    lo, hi = spec.low, spec.high
    if lo is not None and (value <= lo if spec.low_open else value < lo):
        return f'{name} must be {">" if spec.low_open else ">="} {lo:g}, got {value!r}'
    if hi is not None and (value >= hi if spec.high_open else value > hi):
        return f'{name} must be {"<" if spec.high_open else "<="} {hi:g}, got {value!r}'
    if spec.step and lo is not None and (value - lo) % spec.step:
        return f'{name} must be {lo:g} + a multiple of {spec.step}, got {value!r}'
    return ''
