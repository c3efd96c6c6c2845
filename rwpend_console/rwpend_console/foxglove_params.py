"""ROS 2 parameters as the Foxglove WebSocket protocol names and types them (pure).

A parameter is named ``<node>.<parameter>`` with the node's full name, as Foxglove's ROS 2
bridge names them: ``/rwpend/controller.balance.kpp``. Values: numbers, booleans, strings and
their arrays as they are; a double carries the ``float64`` type hint (so 2.0 stays a double on
the wire), a double array ``float64_array``, a byte array goes as base64 with ``byte_array``.
"""
from __future__ import annotations

import re
from typing import Any

from .panel import Field, coerce_value

_NODE_RE = re.compile(r'(/[A-Za-z_][A-Za-z0-9_]*)+')
#: our type name -> the protocol's type hint (None: none needed)
HINTS = {'double': 'float64', 'double_array': 'float64_array', 'byte_array': 'byte_array'}


def split_name(name: str) -> tuple[str, str]:
    """'/rwpend/controller.balance.kpp' -> ('/rwpend/controller', 'balance.kpp');
    ValueError with the reason."""
    node, sep, param = (name or '').partition('.')
    if not sep or not param or not _NODE_RE.fullmatch(node):
        raise ValueError(f'a parameter is named /NAMESPACE/NODE.PARAMETER (e.g. '
                         f'/rwpend/controller.balance.kpp), got {name!r}')
    return node, param


def join_name(node: str, param: str) -> str:
    return f'{node}.{param}'


def to_wire(type_name: str, value: Any) -> tuple[Any, str | None]:
    """(value as a protocol value, type hint)."""
    if type_name == 'byte_array':      # rclpy gives a list of 1-byte bytes objects
        return b''.join(x if isinstance(x, bytes) else bytes([x]) for x in value), HINTS[type_name]
    if type_name == 'double':
        return float(value), HINTS[type_name]
    if type_name == 'double_array':
        return [float(v) for v in value], HINTS[type_name]
    return value, None


def from_wire(node: str, param: str, type_name: str, read_only: bool, value: Any) -> Any:
    """The value a client sent, of the parameter's present type (``type_name``); ValueError
    with the reason (read-only, wrong type) -- the same checks as the console's page."""
    f = Field(node=node, name=param, type=type_name, value=None, read_only=read_only)
    if value is None:
        raise ValueError(f'{param}: parameters of our nodes cannot be unset')
    return coerce_value(f, value)
