"""Small, short-lived ROS 2 clients for the command-line tools (``./rwpend param``, ``gains
--apply``, the lab's monitor, the console): parameters (the standard rcl_interfaces services, as
``ros2 param`` uses them), the controller's mode, the simulator's disturbances, the e-stop, the
graph.

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
from rclpy.parameter import get_parameter_value

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
    """A command-line value as ``ros2 param set`` reads it (rclpy's ``get_parameter_value``, YAML
    1.1): ``3`` -> integer, ``3.0`` -> double, ``true``/``on``/``off``/``yes``/``no`` -> bool,
    ``[1.0, 2.0]`` -> double array, anything else -> string; text YAML cannot read at all
    (``a: b: c``) is a string too. The node reads the value as its parameter's type where the
    tools mean that (``off`` for a mode, ``3`` for a double: rwpend_ros.paramspec)."""
    try:
        pv = get_parameter_value(text)
    except yaml.YAMLError:
        return ParameterValue(type=ParameterType.PARAMETER_STRING, string_value=text)
    except OverflowError:       # an integer array beyond 64 bits
        raise ToolError(f'cannot send {text!r}: a ROS integer parameter has 64 bits') from None
    ints = [pv.integer_value] if pv.type == ParameterType.PARAMETER_INTEGER else list(pv.integer_array_value)
    if any(not -2 ** 63 <= i < 2 ** 63 for i in ints):
        raise ToolError(f'cannot send {text!r}: a ROS integer parameter has 64 bits')
    return pv


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
    elif isinstance(v, list) and all(isinstance(x, bool) for x in v):   # [] too, as rclpy makes it
        pv.type, pv.bool_array_value = ParameterType.PARAMETER_BOOL_ARRAY, v
    elif isinstance(v, list) and v and all(isinstance(x, int) and not isinstance(x, bool) for x in v):
        pv.type, pv.integer_array_value = ParameterType.PARAMETER_INTEGER_ARRAY, v
    elif isinstance(v, list) and v and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
        pv.type, pv.double_array_value = ParameterType.PARAMETER_DOUBLE_ARRAY, [float(x) for x in v]
    elif isinstance(v, list) and v and all(isinstance(x, str) for x in v):
        pv.type, pv.string_array_value = ParameterType.PARAMETER_STRING_ARRAY, v
    else:
        raise ToolError(f'cannot make a ROS parameter of {v!r} (mixed list, mapping, null)')
    return pv


def from_parameter_value(pv: ParameterValue) -> Any:
    if pv.type == ParameterType.PARAMETER_NOT_SET:
        return None
    v = getattr(pv, _FIELDS[pv.type])
    return list(v) if not isinstance(v, (bool, int, float, str)) else v


def _same(a: Any, b: Any) -> bool:
    """The same parameter value (an integer in a file is the same as that double)."""
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, bool) or isinstance(b, bool):
        return a is b
    return a == b


def format_value(v: Any) -> str:
    if isinstance(v, float) and math.isfinite(v):
        return repr(v)
    return yaml.safe_dump(v, default_flow_style=True).strip().removesuffix('...').strip() \
        if isinstance(v, (list, dict)) else str(v)


_TYPE_NAMES = {ParameterType.PARAMETER_NOT_SET: 'not set', ParameterType.PARAMETER_BOOL: 'bool',
               ParameterType.PARAMETER_INTEGER: 'integer', ParameterType.PARAMETER_DOUBLE: 'double',
               ParameterType.PARAMETER_STRING: 'string', ParameterType.PARAMETER_BYTE_ARRAY: 'byte array',
               ParameterType.PARAMETER_BOOL_ARRAY: 'bool array',
               ParameterType.PARAMETER_INTEGER_ARRAY: 'integer array',
               ParameterType.PARAMETER_DOUBLE_ARRAY: 'double array',
               ParameterType.PARAMETER_STRING_ARRAY: 'string array'}


def format_descriptor(d) -> str:
    """A ParameterDescriptor as lines: name, type, read-only; description; range; constraints."""
    head = f'{d.name}: {_TYPE_NAMES.get(d.type, d.type)}' + (', read-only' if d.read_only else '')
    lines = [head]
    if d.description:
        lines.append(f'  {d.description}')
    for r in list(d.floating_point_range) + list(d.integer_range):
        lines.append(f'  range: {format_value(r.from_value)} .. {format_value(r.to_value)}'
                     + (f', step {format_value(r.step)}' if r.step else ''))
    if d.additional_constraints:
        lines.append(f'  constraints: {d.additional_constraints}')
    return '\n'.join(lines)


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
        if len(r.values) != len(names):    # the service answers nothing when one is unknown
            self._unknown(node, names)
        out = {}
        for n, pv in zip(names, r.values):
            if pv.type == ParameterType.PARAMETER_NOT_SET:
                raise ToolError(f'{self.fqn(node)} has no parameter {n!r}')
            out[n] = from_parameter_value(pv)
        return out

    def describe(self, node: str, names: list[str]):
        r = self.call(DescribeParameters, self.fqn(node) + '/describe_parameters',
                      DescribeParameters.Request(names=names))
        if len(r.descriptors) != len(names):
            self._unknown(node, names)
        return r.descriptors

    def _unknown(self, node: str, names: list[str]) -> None:
        declared = set(self.list_params(node))
        missing = [n for n in names if n not in declared] or names
        raise ToolError(f'{self.fqn(node)} has no parameter {", ".join(map(repr, missing))}')

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

    def load(self, node: str, values: dict[str, Any]) -> tuple[list[tuple[str, bool, str]], int]:
        """Set ``values`` (a params file's, typed) one by one as ``ros2 param load`` does, except
        that a read-only parameter given the value it has is left out (a dump loaded back holds
        every one); ([(name, ok, reason)], read-only ones left out)."""
        names = list(values)
        declared = set(self.list_params(node))
        known = [n for n in names if n in declared]
        current = self.get_params(node, known) if known else {}
        read_only = {d.name for d in self.describe(node, known) if d.read_only} if known else set()
        skipped = [n for n in known if n in read_only and _same(current[n], values[n])]
        todo = {n: to_parameter_value(values[n]) for n in names if n not in skipped}
        return (self.set_params(node, todo) if todo else []), len(skipped)

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

    # ------------------------------------------------------------ the graph
    def graph(self, settle: float = 3.0) -> dict[str, dict]:
        """What this host sees of its ROS domain, after ``settle`` s of discovery: {node (full
        name): {'subscriptions': {topic: [publishing nodes]}, 'publications': [topics]}}, this
        tool's own node left out. Subscriptions answer "who reaches this node": on a lab
        network, the publishers of a rig's topics must all be that rig's nodes."""
        end = time.monotonic() + settle
        while time.monotonic() < end:
            rclpy.spin_once(self.node, timeout_sec=0.1)
        me = self.node.get_fully_qualified_name()
        out: dict[str, dict] = {}
        for name, ns in self.node.get_node_names_and_namespaces():
            fqn = f"{ns.rstrip('/')}/{name}"
            if fqn == me:
                continue
            subs = {}
            for topic, _ in self.node.get_subscriber_names_and_types_by_node(name, ns):
                subs[topic] = sorted(f"{i.node_namespace.rstrip('/')}/{i.node_name}"
                                     for i in self.node.get_publishers_info_by_topic(topic)
                                     if f"{i.node_namespace.rstrip('/')}/{i.node_name}" != me)
            pubs = sorted(t for t, _ in self.node.get_publisher_names_and_types_by_node(name, ns))
            out[fqn] = {'subscriptions': subs, 'publications': pubs}
        return out


def foreign_publishers(graph: dict[str, dict],
                       shared: tuple[str, ...] = ('/diagnostics', '/parameter_events', '/rosout', '/clock')) -> list[str]:
    """Where a node takes a topic from a node of another namespace (``shared`` topics, global
    by design, aside): 'subscriber <- publisher on topic' lines; empty when every rig hears
    only itself."""
    out = []
    for node, info in sorted(graph.items()):
        ns = node.rsplit('/', 1)[0]
        for topic, pubs in info['subscriptions'].items():
            if topic in shared:
                continue
            out += [f'{node} <- {pub} on {topic}' for pub in pubs if pub.rsplit('/', 1)[0] != ns]
    return out
