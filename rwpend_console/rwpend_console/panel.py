"""The gains panel's model (pure: plain values in, plain values out; no rclpy).

The panel is built from what a node says of its parameters through the standard services
(``describe_parameters``, ``get_parameters``): names, types, ranges, read-only flags,
descriptions. The console's node turns rcl_interfaces messages into the plain dicts read here:

* :func:`build_fields` -- one :class:`Field` per parameter, grouped by the name's first part
  (``balance.kpp`` -> ``balance``), design parameters (``balance.design.omega0``) marked with
  the gain group they design;
* :func:`coerce_value` -- a value typed on the page, checked against the field (type,
  read-only, and the range and allowed values its descriptor states, judged as the node judges
  them: :func:`rwpend_ros.paramspec.check` on :func:`spec_of` the field) before anything is
  sent: a clear reason, nothing sent, otherwise;
* :func:`design_preview` -- the gains a design would give, and whether the linearized upright
  loop (model 4.8) is stable with them, before the design is applied;
* :func:`range_text`, :func:`notes_text` -- what a field takes, written for a reader: its range
  with the open ends its constraints state (``≥ 1 and < 183.725``), bounds in 6 significant
  digits (:func:`rwpend_console.fmt.number_text`, as the node writes them when it refuses a
  value), and the constraints that are not bounds; a field's value is shown whole
  (:func:`rwpend_console.fmt.value_text`).
"""
from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, field
from typing import Any, Mapping

from .fmt import number_text, value_text

#: rcl_interfaces/ParameterType numbers -> the names used here (and on the page)
TYPE_NAMES = {0: 'not_set', 1: 'bool', 2: 'integer', 3: 'double', 4: 'string', 5: 'byte_array',
              6: 'bool_array', 7: 'integer_array', 8: 'double_array', 9: 'string_array'}
TYPE_NUMBERS = {v: k for k, v in TYPE_NAMES.items()}
#: the gain groups a design parameter group designs (rwpend_control.parameters.DESIGN_GROUPS)
DESIGN_MARK = '.design.'


@dataclass
class Field:
    """One parameter as the page shows it."""

    node: str
    name: str
    type: str                       # TYPE_NAMES value
    value: Any
    read_only: bool = False
    description: str = ''
    constraints: str = ''           # the descriptor's additional_constraints
    minimum: float | None = None    # from floating_point_range / integer_range
    maximum: float | None = None
    step: float | None = None
    group: str = ''                 # first part of the name ('' for a plain name)
    designs: str = ''               # the gain group this design parameter designs

    def as_dict(self) -> dict:
        """The field for the page: its data, and the texts the page shows (``value_text``: the
        whole value, ``range_text``, ``notes``)."""
        return {**asdict(self), 'value_text': value_text(self.type, self.value),
                'range_text': range_text(self), 'notes': notes_text(self)}


def _range(descr: Mapping) -> tuple[float | None, float | None, float | None]:
    for key in ('floating_point_range', 'integer_range'):
        r = descr.get(key) or []
        if r:
            lo, hi, step = r[0].get('from_value'), r[0].get('to_value'), r[0].get('step')
            return lo, hi, (step or None)
    return None, None, None


def build_fields(node: str, values: Mapping[str, tuple[str, Any]],
                 descriptors: Mapping[str, Mapping]) -> list[Field]:
    """Fields of ``node`` from ``values`` ({name: (type name, value)}) and ``descriptors``
    ({name: {'description', 'read_only', 'additional_constraints', 'floating_point_range':
    [{'from_value', 'to_value', 'step'}], 'integer_range': [...]}}), sorted by group and name;
    a parameter without a descriptor is shown read-only (the node did not describe it)."""
    out = []
    for name, (type_name, value) in values.items():
        d = descriptors.get(name)
        lo, hi, step = _range(d or {})
        group = name.split('.', 1)[0] if '.' in name else ''
        designs = name.split(DESIGN_MARK, 1)[0] if DESIGN_MARK in name else ''
        out.append(Field(node=node, name=name, type=type_name, value=value,
                         read_only=True if d is None else bool(d.get('read_only')),
                         description=(d or {}).get('description', ''),
                         constraints=(d or {}).get('additional_constraints', ''),
                         minimum=lo, maximum=hi, step=step, group=group, designs=designs))
    out.sort(key=lambda f: (f.group, DESIGN_MARK not in f.name, f.name))
    return out


def _number(text: Any, name: str) -> float:
    if isinstance(text, bool):
        raise ValueError(f'{name}: a number, got {text!r}')
    if isinstance(text, (int, float)):
        v = float(text)
    elif isinstance(text, str):
        try:
            v = float(text.strip())
        except ValueError:
            raise ValueError(f'{name}: a number, got {text!r}') from None
    else:
        raise ValueError(f'{name}: a number, got {text!r}')
    if not math.isfinite(v):
        raise ValueError(f'{name}: a finite number, got {text!r}')
    return v


def _integer(text: Any, name: str) -> int:
    v = _number(text, name)
    if v != int(v):
        raise ValueError(f'{name}: an integer, got {text!r}')
    return int(v)


def _boolean(text: Any, name: str) -> bool:
    if isinstance(text, bool):
        return text
    if isinstance(text, str) and text.strip().lower() in ('true', 'false'):
        return text.strip().lower() == 'true'
    raise ValueError(f'{name}: true or false, got {text!r}')


def _string(text: Any, name: str) -> str:
    if not isinstance(text, str):
        raise ValueError(f'{name}: text, got {text!r}')
    return text


_SCALARS = {'double': _number, 'integer': _integer, 'bool': _boolean, 'string': _string}


_BOUND = re.compile(r'(>=|>|<=|<) ([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)')


def _same(text_bound: float, exact: float | None) -> float:
    if exact is not None and abs(text_bound - exact) <= 1e-5 * max(1.0, abs(exact)):
        return exact
    return text_bound


def spec_of(f: Field):
    """The :class:`rwpend_ros.paramspec.ParamSpec` a field's descriptor states: type, range,
    read-only, and from its additional constraints the allowed values ('one of: a, b') and
    one-sided or open bounds ('> 0', '<= 5') as :meth:`ParamSpec.constraint_text` writes them;
    other constraints (e.g. 'closed loop (4.8) stable') are the node's to judge."""
    from rwpend_ros.paramspec import KINDS, ParamSpec
    low, high = f.minimum, f.maximum
    low_open = high_open = False
    choices: tuple[str, ...] = ()
    for part in (f.constraints or '').split('; '):
        m = _BOUND.fullmatch(part.strip())
        if part.startswith('one of: '):
            choices = tuple(c.strip() for c in part[len('one of: '):].split(','))
        elif m:   # the text has 6 digits (:g): the range's exact bound where it is that bound
            v = float(m.group(2))
            if m.group(1).startswith('>'):
                low, low_open = _same(v, f.minimum), m.group(1) == '>'
            else:
                high, high_open = _same(v, f.maximum), m.group(1) == '<'
    step = int(f.step) if f.type == 'integer' and f.step else 0
    return ParamSpec(f.name, None, f.description, low=low, high=high, low_open=low_open, high_open=high_open,
                     step=step, choices=choices if f.type == 'string' else (), read_only=f.read_only,
                     kind=f.type if f.type in KINDS else 'string')


def _bound_text(v: float, integer: bool) -> str:
    return number_text(int(v) if integer and float(v).is_integer() else float(v))


def range_text(f: Field) -> str:
    """The values a number field takes, as the page shows them: ``-10 .. 0`` (both bounds, both
    closed), ``≥ 1 and < 183.725`` (an open end), ``> 0`` / ``≤ 5`` (one bound), with ``, step
    N`` for an integer range whose step is not 1; '' for a field that is not a number or has no
    bounds. What the descriptor states: the range and the bounds of its constraints
    (:func:`spec_of`)."""
    if f.type not in ('double', 'integer'):
        return ''
    spec = spec_of(f)
    integer = f.type == 'integer'
    lo = None if spec.low is None else _bound_text(spec.low, integer)
    hi = None if spec.high is None else _bound_text(spec.high, integer)
    low_op = '>' if spec.low_open else '≥'
    high_op = '<' if spec.high_open else '≤'
    if lo is not None and hi is not None:
        text = f'{lo} .. {hi}' if not (spec.low_open or spec.high_open) else f'{low_op} {lo} and {high_op} {hi}'
    elif lo is not None:
        text = f'{low_op} {lo}'
    elif hi is not None:
        text = f'{high_op} {hi}'
    else:
        return ''
    if spec.step and spec.step != 1:
        text += f', step {spec.step}'
    return text


def notes_text(f: Field) -> str:
    """The field's constraints that are not bounds (those are in :func:`range_text`): the
    allowed values ('one of: a, b'), what the node judges itself ('closed loop (4.8) stable')."""
    parts = [p.strip() for p in (f.constraints or '').split('; ') if p.strip()]
    if f.type in ('double', 'integer'):
        parts = [p for p in parts if not _BOUND.fullmatch(p)]
    return '; '.join(parts)


def coerce_value(f: Field, raw: Any) -> Any:
    """The value to send for ``raw`` (a JSON value from the page), of the field's type; a
    ValueError with the reason when it cannot be (read-only, wrong type, not finite, outside
    the range or not one of the allowed values its descriptor states). What the descriptor
    cannot state (a gain that makes the loop unstable) the node refuses with its reason."""
    from rwpend_ros.paramspec import check
    if f.read_only:
        raise ValueError(f'{f.name} is read-only (set at start: --set or --params)')
    if f.type in _SCALARS:
        value = _SCALARS[f.type](raw, f.name)
    elif f.type.endswith('_array') and f.type[:-6] in _SCALARS:
        if not isinstance(raw, list) or not raw:
            raise ValueError(f'{f.name}: a non-empty list, got {raw!r}')
        return [_SCALARS[f.type[:-6]](x, f.name) for x in raw]
    else:
        raise ValueError(f'{f.name}: parameters of type {f.type} cannot be set from the console')
    reason = check(spec_of(f), value)
    if reason:
        raise ValueError(reason)
    return value


@dataclass
class Preview:
    """What a design gives: the gains, and for balance/patch the stability verdict of (4.8)."""

    ok: bool
    gains: dict = field(default_factory=dict)
    stable: bool | None = None
    reason: str = ''

    def as_dict(self) -> dict:
        return asdict(self)


def design_preview(rig, group: str, designs: Mapping[str, Any], changes: Mapping[str, Any]) -> Preview:
    """The gains of ``group`` designed from the node's design parameters ``designs`` (all
    ``<group>.design.*`` values it holds) with ``changes`` applied, for ``rig``
    (rwpend_model.rig.Rig); the controller's own functions compute them
    (:func:`rwpend_control.supervisor.gains_from_design`, :func:`rwpend_control.design.check_stable`)."""
    from rwpend_control.design import check_stable
    from rwpend_control.parameters import DESIGN_GROUPS
    from rwpend_control.supervisor import gains_from_design
    if group not in DESIGN_GROUPS:
        return Preview(False, reason=f'no design group {group!r} (one of {", ".join(DESIGN_GROUPS)})')
    prefix = f'{group}{DESIGN_MARK}'
    bad = [n for n in changes if not n.startswith(prefix)]
    if bad:
        return Preview(False, reason=f'{", ".join(bad)}: not a design parameter of {group}')
    spec = {k[len(prefix):]: v for k, v in {**designs, **changes}.items() if k.startswith(prefix)}
    try:
        gains = gains_from_design(rig, group, spec)
    except (ValueError, TypeError, KeyError, ArithmeticError) as exc:
        return Preview(False, reason=f'{group} design: {exc}')
    if group not in ('balance', 'patch'):
        return Preview(True, gains)
    g = {k.split('.', 1)[1]: v for k, v in gains.items()}
    stable, why = check_stable(rig, {'kpp': g['kpp'], 'kdp': g['kdp'], 'kpr': g.get('kpr', 0.0),
                                     'kdr': g['kdr']})
    return Preview(True, gains, stable, why)
