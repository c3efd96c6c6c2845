"""A node's parameters through the standard services (``list_parameters``,
``describe_parameters``, ``get_parameters``, ``set_parameters``), turned into the plain values
of :mod:`rwpend_console.panel`. Shared by the console and the bridge; every call goes through
a ``call(srv_type, name, request)`` function (:meth:`rwpend_console.rosside.DomainWatcher.call`)."""
from __future__ import annotations

from typing import Any, Callable

from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters

from rwpend_ros.tools import ToolError, from_parameter_value, to_parameter_value

from .panel import TYPE_NAMES, Field, build_fields

Call = Callable[[Any, str, Any], Any]


def _range(r) -> list[dict]:
    return [{'from_value': x.from_value, 'to_value': x.to_value, 'step': x.step} for x in r]


def descriptor_dict(d) -> dict:
    return {'description': d.description, 'read_only': bool(d.read_only),
            'additional_constraints': d.additional_constraints,
            'floating_point_range': _range(d.floating_point_range), 'integer_range': _range(d.integer_range)}


def list_names(call: Call, node: str) -> list[str]:
    r = call(ListParameters, f'{node}/list_parameters', ListParameters.Request(depth=0))
    return sorted(r.result.names)


def get_typed(call: Call, node: str, names: list[str]) -> dict[str, tuple[str, Any]]:
    """{name: (type name, value)} of the parameters the node has (unset ones left out)."""
    r = call(GetParameters, f'{node}/get_parameters', GetParameters.Request(names=list(names)))
    return {n: (TYPE_NAMES.get(pv.type, 'not_set'), from_parameter_value(pv))
            for n, pv in zip(names, r.values) if pv.type != 0}


def describe(call: Call, node: str, names: list[str]) -> dict[str, dict]:
    r = call(DescribeParameters, f'{node}/describe_parameters', DescribeParameters.Request(names=list(names)))
    return {d.name: descriptor_dict(d) for d in r.descriptors}


def read_fields(call: Call, node: str, names: list[str] | None = None) -> list[Field]:
    """The panel's fields of ``node`` (all its parameters, or ``names``)."""
    names = list_names(call, node) if names is None else list(names)
    if not names:
        return []
    return build_fields(node, get_typed(call, node, names), describe(call, node, names))


def set_values(call: Call, node: str, values: dict[str, Any]) -> list[tuple[str, bool, str]]:
    """Set each parameter on its own (as ``ros2 param set``): [(name, ok, reason)]; a value that
    cannot be a ROS parameter comes back refused with the reason, nothing sent for it."""
    out, msgs = [], []
    for name, value in values.items():
        try:
            msgs.append(ParameterMsg(name=name, value=to_parameter_value(value)))
        except ToolError as exc:
            out.append((name, False, str(exc)))
    if msgs:
        r = call(SetParameters, f'{node}/set_parameters', SetParameters.Request(parameters=msgs))
        out += [(m.name, res.successful, res.reason) for m, res in zip(msgs, r.results)]
    return out
