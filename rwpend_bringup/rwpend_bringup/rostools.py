"""Small ROS 2 clients of the CLI: parameters (the standard rcl_interfaces services, as
``ros2 param`` uses them), the controller's mode, the simulator's disturbances, the e-stop.

Every call is bounded in time and returns (ok, message); nothing here raises on a missing node.
"""
from __future__ import annotations

import math
import time
from typing import Any

import rclpy
import yaml
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import (DescribeParameters, GetParameters, ListParameters, SetParameters,
                                SetParametersAtomically)
from rclpy.node import Node

#: ParameterType -> field of ParameterValue
_FIELDS = {
    ParameterType.PARAMETER_BOOL: 'bool_value', ParameterType.PARAMETER_INTEGER: 'integer_value',
    ParameterType.PARAMETER_DOUBLE: 'double_value', ParameterType.PARAMETER_STRING: 'string_value',
    ParameterType.PARAMETER_BYTE_ARRAY: 'byte_array_value',
    ParameterType.PARAMETER_BOOL_ARRAY: 'bool_array_value',
    ParameterType.PARAMETER_INTEGER_ARRAY: 'integer_array_value',
    ParameterType.PARAMETER_DOUBLE_ARRAY: 'double_array_value',
    ParameterType.PARAMETER_STRING_ARRAY: 'string_array_value',
}


class ToolError(RuntimeError):
    """A CLI request that could not be carried out (the message says why)."""


def parse_value(text: str) -> ParameterValue:
    """A command-line value as ``ros2 param set`` reads it (YAML): 3 -> int, 3.0 -> double,
    true -> bool, [1.0, 2.0] -> double array, anything else -> string."""
    try:
        v = yaml.safe_load(text)
    except yaml.YAMLError:
        v = text
    return to_parameter_value(text if v is None and text.strip() not in ('null', '~', '') else v)


def to_parameter_value(v: Any) -> ParameterValue:
    pv = ParameterValue()
    if isinstance(v, bool):
        pv.type, pv.bool_value = ParameterType.PARAMETER_BOOL, v
    elif isinstance(v, int):
        pv.type, pv.integer_value = ParameterType.PARAMETER_INTEGER, v
    elif isinstance(v, float):
        pv.type, pv.double_value = ParameterType.PARAMETER_DOUBLE, v
    elif isinstance(v, str):
        pv.type, pv.string_value = ParameterType.PARAMETER_STRING, v
    elif isinstance(v, list) and v and all(isinstance(x, bool) for x in v):
        pv.type, pv.bool_array_value = ParameterType.PARAMETER_BOOL_ARRAY, v
    elif isinstance(v, list) and v and all(isinstance(x, int) and not isinstance(x, bool) for x in v):
        pv.type, pv.integer_array_value = ParameterType.PARAMETER_INTEGER_ARRAY, v
    elif isinstance(v, list) and v and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
        pv.type, pv.double_array_value = ParameterType.PARAMETER_DOUBLE_ARRAY, [float(x) for x in v]
    elif isinstance(v, list) and v and all(isinstance(x, str) for x in v):
        pv.type, pv.string_array_value = ParameterType.PARAMETER_STRING_ARRAY, v
    else:
        raise ToolError(f'cannot make a ROS parameter of {v!r} (empty or mixed list, mapping, null)')
    return pv


def from_parameter_value(pv: ParameterValue) -> Any:
    if pv.type == ParameterType.PARAMETER_NOT_SET:
        return None
    v = getattr(pv, _FIELDS[pv.type])
    return list(v) if not isinstance(v, (bool, int, float, str)) else v


def format_value(v: Any) -> str:
    if isinstance(v, float) and math.isfinite(v):
        return repr(v)
    return yaml.safe_dump(v, default_flow_style=True).strip().removesuffix('...').strip() \
        if isinstance(v, (list, dict)) else str(v)


class RosTool:
    """A short-lived client node; use as a context manager."""

    def __init__(self, namespace: str = '/rwpend', timeout: float = 5.0) -> None:
        self.namespace = '/' + namespace.strip('/') if namespace.strip('/') else ''
        self.timeout = timeout

    def __enter__(self) -> 'RosTool':
        from rwpend_ros.transport import apply_transport_or_exit
        apply_transport_or_exit()  # before rclpy.init
        rclpy.init(args=[])  # not sys.argv (a value like a:=b would be read as a remap)
        self.node = Node('rwpend_cli', namespace='/', start_parameter_services=False)
        return self

    def __exit__(self, *exc) -> None:
        self.node.destroy_node()
        rclpy.try_shutdown()

    # ------------------------------------------------------------ helpers
    def fqn(self, node: str) -> str:
        """'controller' -> '/rwpend/controller'; absolute names stay."""
        return node if node.startswith('/') else f'{self.namespace}/{node}'

    def call(self, srv_type, name: str, request):
        client = self.node.create_client(srv_type, name)
        try:
            if not client.wait_for_service(timeout_sec=self.timeout):
                raise ToolError(f'service {name} is not available (is the stack running, in this '
                                f'namespace and ROS_DOMAIN_ID?)')
            future = client.call_async(request)
            end = time.monotonic() + self.timeout
            while not future.done() and time.monotonic() < end:
                rclpy.spin_once(self.node, timeout_sec=0.05)
            if not future.done():
                raise ToolError(f'service {name} did not answer within {self.timeout:g} s')
            return future.result()
        finally:
            self.node.destroy_client(client)

    # ------------------------------------------------------------ parameters
    def list_params(self, node: str) -> list[str]:
        r = self.call(ListParameters, self.fqn(node) + '/list_parameters', ListParameters.Request(depth=0))
        return sorted(r.result.names)

    def get_params(self, node: str, names: list[str]) -> dict[str, Any]:
        r = self.call(GetParameters, self.fqn(node) + '/get_parameters', GetParameters.Request(names=names))
        out = {}
        for n, pv in zip(names, r.values):
            if pv.type == ParameterType.PARAMETER_NOT_SET:
                raise ToolError(f'{self.fqn(node)} has no parameter {n!r}')
            out[n] = from_parameter_value(pv)
        return out

    def describe(self, node: str, names: list[str]):
        r = self.call(DescribeParameters, self.fqn(node) + '/describe_parameters',
                      DescribeParameters.Request(names=names))
        return r.descriptors

    def set_params(self, node: str, values: dict[str, ParameterValue]) -> list[tuple[str, bool, str]]:
        """Set atomically-per-parameter as ``ros2 param set`` does; [(name, ok, reason)]."""
        req = SetParameters.Request(parameters=[ParameterMsg(name=n, value=v) for n, v in values.items()])
        r = self.call(SetParameters, self.fqn(node) + '/set_parameters', req)
        return [(n, res.successful, res.reason) for n, res in zip(values, r.results)]

    def set_params_atomically(self, node: str, values: dict[str, ParameterValue]) -> tuple[bool, str]:
        """All or nothing (a gain set is validated as a whole by the controller)."""
        req = SetParametersAtomically.Request(
            parameters=[ParameterMsg(name=n, value=v) for n, v in values.items()])
        r = self.call(SetParametersAtomically, self.fqn(node) + '/set_parameters_atomically', req)
        return r.result.successful, r.result.reason

    def dump(self, node: str) -> str:
        """The node's parameters as a ROS 2 params file (loadable with --params-file)."""
        names = self.list_params(node)
        values = self.get_params(node, names) if names else {}
        nested: dict = {}
        for name in names:
            d = nested
            parts = name.split('.')
            for p in parts[:-1]:
                d = d.setdefault(p, {})
            d[parts[-1]] = values[name]
        return yaml.safe_dump({self.fqn(node): {'ros__parameters': nested}}, sort_keys=True)

    # ------------------------------------------------------------ stack services
    def set_mode(self, mode: str) -> tuple[bool, str]:
        from rwpend_msgs.srv import SetMode
        r = self.call(SetMode, self.fqn('controller') + '/set_mode', SetMode.Request(mode=mode))
        return r.success, r.message

    def disturb(self, kind: int, magnitude: float, duration: float = 0.0) -> tuple[bool, str]:
        from rwpend_msgs.srv import Disturb
        req = Disturb.Request(kind=kind, magnitude=float(magnitude), duration=float(duration))
        r = self.call(Disturb, self.fqn('sim') + '/disturb', req)
        return r.success, r.message

    def estop(self, on: bool) -> list[tuple[str, bool, str]]:
        """Raise or clear the latched e-stop on every plant-side node that serves ``~/estop``."""
        from std_srvs.srv import SetBool
        targets = []
        end = time.monotonic() + self.timeout   # discovery of a loaded host can take seconds
        while time.monotonic() < end:
            names = [n for n, types in self.node.get_service_names_and_types()
                     if n.startswith(self.namespace + '/') and n.endswith('/estop')
                     and 'std_srvs/srv/SetBool' in types]
            if names:
                targets = sorted(set(names))
                break
            rclpy.spin_once(self.node, timeout_sec=0.1)
            time.sleep(0.05)
        if not targets:
            raise ToolError(f'no e-stop service under {self.namespace or "/"} (is the stack running?)')
        out = []
        for name in targets:
            r = self.call(SetBool, name, SetBool.Request(data=on))
            out.append((name, r.success, r.message))
        return out
