"""A node's parameters as ROS 2 tools expect them: each declared with its real type, description,
range and read-only flag (:class:`ParameterTable`, from :class:`rwpend_ros.paramspec.ParamSpec`),
values that ``ros2 param set`` / ``load`` send read as the parameter's type before rclpy checks
the type (a pre-set callback, :func:`rwpend_ros.paramspec.coerce`); the rig's data (read-only,
from the one rig YAML: :func:`declare_rig`); :class:`ConfigError` for a configuration the node
refuses (reported, exit status 2)."""
from __future__ import annotations

import difflib
from dataclasses import fields
from typing import Any, Iterable

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                SetParametersResult)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.parameter import Parameter

from rwpend_model.rig import (DESCRIPTIONS, INT_FIELDS, MAY_BE_ZERO, PARAM_PREFIX,
                              SAMPLE_PERIOD_LIMITS, Rig, default_rig_file, read_params_file)
from rwpend_ros.paramspec import ParamSpec, check, coerce

#: ParamSpec kind -> rclpy parameter type
_TYPES = {'bool': Parameter.Type.BOOL, 'integer': Parameter.Type.INTEGER,
          'double': Parameter.Type.DOUBLE, 'string': Parameter.Type.STRING,
          'bool_array': Parameter.Type.BOOL_ARRAY, 'integer_array': Parameter.Type.INTEGER_ARRAY,
          'double_array': Parameter.Type.DOUBLE_ARRAY, 'string_array': Parameter.Type.STRING_ARRAY}


class ConfigError(ValueError):
    """A node's configuration (parameters) is invalid: the node reports it and exits with status 2."""


def refuse_undeclared(nodes) -> None:
    """:meth:`ParameterTable.refuse_undeclared` for every node of ``nodes`` that has a
    ``param_table`` (the stack's own); the first ConfigError is raised."""
    for node in nodes:
        table = getattr(node, 'param_table', None)
        if isinstance(table, ParameterTable):
            table.refuse_undeclared()


def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """The ParameterDescriptor of ``spec``: type, description, read-only, range (both bounds
    given), additional constraints (allowed values, open or one-sided bounds)."""
    d = ParameterDescriptor(name=spec.name, type=_TYPES[spec.kind].value,
                            description=spec.description, read_only=spec.read_only,
                            additional_constraints=spec.constraint_text())
    if spec.range is not None:
        lo, hi = spec.range
        if spec.kind == 'integer':
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=spec.step)]
        elif spec.kind == 'double':
            d.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)]
    return d


class ParameterTable:
    """The parameters a node declares (:meth:`declare`) and the two callbacks that keep them
    to their specs, registered on ``node`` at construction:

    * pre-set: a value of another type is read as the parameter's (:func:`coerce`: an integer
      for a double, false for 'off', ...) before rclpy's type check; anything else is left as
      it came, and rclpy refuses it with its reason ("Wrong parameter type, expected ...");
    * on-set: a value outside the range or the allowed values is refused with the reason
      (:func:`check`; rclpy's own range check does not know open bounds or allowed strings).

    The node's own on-set callback (registered later, so called first) judges its values as a
    whole. Parameters rclpy declares itself (``use_sim_time`` ...) are left to rclpy.
    """

    def __init__(self, node) -> None:
        self.node = node
        self.specs: dict[str, ParamSpec] = {}
        node.add_pre_set_parameters_callback(self.convert)
        node.add_on_set_parameters_callback(self.refuse_invalid)

    def declare(self, specs: Iterable[ParamSpec]) -> dict[str, Any]:
        """Declare ``specs`` and return their values (the override given to the node, read by
        :func:`coerce`, else the default; None for a parameter without default and value).
        ConfigError with the reason for a value of another type, out of range or not allowed."""
        values = {}
        for spec in specs:
            values[spec.name] = self._declare(spec)
            self.specs[spec.name] = spec
        return values

    def _declare(self, spec: ParamSpec) -> Any:
        node = self.node
        desc = descriptor(spec)
        try:
            if spec.default is None:
                p = node.declare_parameter(spec.name, _TYPES[spec.kind], desc)
            else:
                p = node.declare_parameter(spec.name, spec.default, desc)
        except (InvalidParameterTypeException, InvalidParameterValueException):
            pass    # the override has another type or is out of range: read it as given
        else:
            if p.type_ == Parameter.Type.NOT_SET:
                return None
            reason = check(spec, p.value)
            if reason:
                raise ConfigError(reason)
            return p.value
        given = node.declare_parameter(spec.name, None, ParameterDescriptor(dynamic_typing=True)).value
        node.undeclare_parameter(spec.name)
        try:
            value = coerce(spec, given)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        reason = check(spec, value)
        if reason:
            raise ConfigError(reason)
        return node.declare_parameter(spec.name, value, descriptor(spec), ignore_override=True).value

    def undeclared_overrides(self) -> list[str]:
        """The names given to the node (params files, ``-p``, ``--set``) that it did not declare:
        rclpy ignores them without a word, so a misspelt ``balance.kp`` would leave the default
        in place. Sorted; empty when rclpy does not say which overrides it was given."""
        given = getattr(self.node, '_parameter_overrides', None) or {}
        return sorted(n for n in given if not self.node.has_parameter(n))

    def refuse_undeclared(self) -> None:
        """ConfigError naming every override the node did not declare (:meth:`undeclared_overrides`),
        with the nearest declared names: called once the node has declared all of its own."""
        unknown = self.undeclared_overrides()
        if not unknown:
            return
        declared = list(self.node.list_parameters([], 0).names)
        said = []
        for name in unknown:
            near = difflib.get_close_matches(name, declared, n=3)
            said.append(f'{name!r}' + (f' (did you mean {", ".join(near)}?)' if near else ''))
        raise ConfigError(f'{self.node.get_fully_qualified_name()} has no parameter {"; ".join(said)}: '
                          '`./rwpend param list` (ros2 param list) names those it has')

    def convert(self, params: list[Parameter]) -> list[Parameter]:
        """Pre-set callback: each value read as its parameter's type where the tools' rules allow
        (:func:`coerce`), one Parameter for each given, in order."""
        out = []
        for p in params:
            spec = self.specs.get(p.name)
            if spec is not None and p.type_ != _TYPES[spec.kind] and p.type_ != Parameter.Type.NOT_SET:
                try:
                    p = Parameter(p.name, value=coerce(spec, p.value))
                except (ValueError, TypeError):
                    pass    # refused by rclpy's type check, with its reason
            out.append(p)
        return out

    def refuse_invalid(self, params: list[Parameter]) -> SetParametersResult:
        """On-set callback: refuse values outside their spec's range or allowed values."""
        reasons = []
        for p in params:
            spec = self.specs.get(p.name)
            if spec is not None and p.type_ == _TYPES[spec.kind]:
                try:
                    reason = check(spec, p.value)
                except (TypeError, ValueError) as exc:   # pragma: no cover - typed above
                    reason = f'{p.name}: {exc}'
                if reason:
                    reasons.append(reason)
        return SetParametersResult(successful=not reasons, reason='; '.join(reasons))


def rig_specs(prefix: str = PARAM_PREFIX, note: str = ' (rig.yaml)') -> list[ParamSpec]:
    """The ``rig.*`` parameters: read-only, defaults from the shipped rig YAML, descriptions and
    bounds from :mod:`rwpend_model.rig`.  ``prefix``: another name for the same set (the
    simulator's ``model_rig.*``), ``note`` the end of their descriptions."""
    defaults = read_params_file(default_rig_file())
    specs = []
    for f in fields(Rig):
        value = defaults.get(PARAM_PREFIX + f.name, getattr(Rig, f.name))
        name = prefix + f.name
        value = int(value) if f.name in INT_FIELDS else float(value)
        low, high = (SAMPLE_PERIOD_LIMITS if f.name == 'sample_period' else (0, None))
        specs.append(ParamSpec(name, value, DESCRIPTIONS[f.name] + note, low=low, high=high,
                               low_open=f.name not in MAY_BE_ZERO and f.name != 'sample_period',
                               read_only=True))
    return specs


def declare_rig(table: ParameterTable, prefix: str = PARAM_PREFIX, note: str = ' (rig.yaml)') -> Rig:
    """Declare every ``rig.*`` parameter (read-only, defaults from the rig YAML) and return the Rig.

    Values come from the params file / overrides given to the node; the shipped rig YAML only
    provides the defaults. Raises ConfigError with the reasons when the values are invalid.
    ``prefix``: another name for the same set (the simulator's ``model_rig.*``).
    """
    values = {PARAM_PREFIX + k[len(prefix):]: v for k, v in table.declare(rig_specs(prefix, note)).items()}
    try:
        return Rig.from_params(values)
    except ValueError as exc:
        raise ConfigError(str(exc)) from exc
