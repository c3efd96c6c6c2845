"""rwpend_ros.tools without a running node: values parsed as ``ros2 param set`` parses
them (YAML 1.1), descriptors printed, file values compared."""
import pytest

pytest.importorskip('rclpy')

from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, ParameterType  # noqa: E402

from rwpend_ros.tools import (ToolError, _same, format_descriptor, parse_value,  # noqa: E402
                              to_parameter_value)

T = ParameterType


@pytest.mark.parametrize('text, kind, value', [
    ('3', T.PARAMETER_INTEGER, 3), ('3.0', T.PARAMETER_DOUBLE, 3.0), ('off', T.PARAMETER_BOOL, False),
    ('on', T.PARAMETER_BOOL, True), ('no', T.PARAMETER_BOOL, False), ('auto', T.PARAMETER_STRING, 'auto'),
    ('1e3', T.PARAMETER_STRING, '1e3'), ('.nan', T.PARAMETER_DOUBLE, None), ('[1.0, 2.0]', T.PARAMETER_DOUBLE_ARRAY, [1.0, 2.0]),
    ('[1, 2.5]', T.PARAMETER_STRING, '[1, 2.5]'), ('a: b: c', T.PARAMETER_STRING, 'a: b: c'),
    ('"off"', T.PARAMETER_STRING, 'off'), ('', T.PARAMETER_STRING, ''),
])
def test_parse_value_as_ros2_param_set(text, kind, value):
    pv = parse_value(text)
    assert pv.type == kind
    field = {T.PARAMETER_INTEGER: 'integer_value', T.PARAMETER_DOUBLE: 'double_value',
             T.PARAMETER_BOOL: 'bool_value', T.PARAMETER_STRING: 'string_value',
             T.PARAMETER_DOUBLE_ARRAY: 'double_array_value'}[kind]
    got = getattr(pv, field)
    if value is None:
        assert got != got    # nan
    else:
        assert (list(got) if kind == T.PARAMETER_DOUBLE_ARRAY else got) == value


def test_too_big_an_integer_is_a_tool_error():
    for text in (str(2 ** 70), f'[1, {2 ** 70}]'):
        with pytest.raises(ToolError, match='64 bits'):
            parse_value(text)
    assert parse_value(str(-2 ** 63)).integer_value == -2 ** 63


def test_file_values_and_descriptors():
    assert to_parameter_value([]).type == T.PARAMETER_BOOL_ARRAY
    assert to_parameter_value([1, 2.5]).double_array_value.tolist() == [1.0, 2.5]
    assert _same(3, 3.0) and _same([1, 2], [1.0, 2.0]) and not _same(True, 1) and not _same('a', 'b')
    d = ParameterDescriptor(name='balance.kpp', type=T.PARAMETER_DOUBLE, description='a gain',
                            additional_constraints='stable', read_only=True,
                            floating_point_range=[FloatingPointRange(from_value=-1e4, to_value=1e4)])
    assert format_descriptor(d) == ('balance.kpp: double, read-only\n  a gain\n'
                                    '  range: -10000.0 .. 10000.0\n  constraints: stable')
