"""rwpend_ros.paramspec (pure): a parameter's spec, values read as its type by the tools' rules."""
import math

import pytest

from rwpend_ros.paramspec import ParamSpec, check, coerce, kind_of

MODE = ParamSpec('mode', 'off', 'operating mode', choices=('off', 'balance', 'auto'))
SWITCH = ParamSpec('switch', 'on', 'a switch', choices=('on', 'off'))
GAIN = ParamSpec('gain', -1.0, 'a gain', low=-10.0, high=0.0)
OMEGA = ParamSpec('omega0', '1.5wp', 'a frequency', numbers_as_text=True)
COUNT = ParamSpec('count', 3, 'a count', low=1, high=10)
SIGN = ParamSpec('sign', 1, 'a sign', low=-1, high=1, step=2)
TAPS = ParamSpec('taps', [-1.0], 'times')
DESIGNED = ParamSpec('k', None, 'designed at start', kind='double')


def test_kinds():
    assert [kind_of(v) for v in (True, 3, 3.0, 'x', [1.0], [1], ['a'], [False])] == [
        'bool', 'integer', 'double', 'string', 'double_array', 'integer_array', 'string_array',
        'bool_array']
    assert DESIGNED.kind == 'double' and TAPS.kind == 'double_array'
    for bad in ([], [1, 'a'], None, {'a': 1}):
        with pytest.raises(ValueError):
            kind_of(bad)
    with pytest.raises(ValueError, match='not of type'):
        ParamSpec('x', 1, 'an integer said to be a double', kind='double')


def test_what_the_tools_send_is_read_as_the_parameter_type():
    assert coerce(GAIN, 3) == 3.0 and isinstance(coerce(GAIN, 3), float)      # set gain 3
    assert coerce(GAIN, '1e-05') == 1e-05          # YAML 1.1 leaves 1e-05 a string (load of a dump)
    assert coerce(GAIN, ' -2.5E+3 ') == -2500.0
    assert coerce(MODE, False) == 'off'            # set mode off / a dumped 'off' loaded back
    assert coerce(SWITCH, True) == 'on' and coerce(SWITCH, False) == 'off'
    assert coerce(OMEGA, 13.3) == '13.3' and coerce(OMEGA, 20) == '20'
    assert coerce(TAPS, [0, 2.5]) == [0.0, 2.5] and coerce(TAPS, []) == []
    assert coerce(DESIGNED, 2) == 2.0
    assert coerce(COUNT, 4) == 4 and coerce(MODE, 'auto') == 'auto'


@pytest.mark.parametrize('spec, value, expected', [
    (MODE, True, "mode must be a string, got True (YAML 1.1 reads on/off/yes/no/true/false as booleans)"),
    (GAIN, 'abc', "gain must be a number, got 'abc'"),
    (GAIN, True, 'gain must be a number, got True'),
    (GAIN, 'nan', "gain must be a number, got 'nan'"),
    (COUNT, 2.5, 'count must be an integer, got 2.5'),
    (COUNT, 3.0, 'count must be an integer, got 3.0'),
    (COUNT, '3', "count must be an integer, got '3'"),
    (OMEGA, False, 'omega0 must be a string or a number, got False'),
    (TAPS, 'x', "taps must be a list of numbers, got 'x'"),
    (TAPS, ['1.0'], "taps must be a list of numbers, got ['1.0']"),
    (ParamSpec('flag', True, 'a flag'), 1, 'flag must be true or false, got 1'),
    (GAIN, None, 'gain must be a number, got None'),
])
def test_anything_else_is_refused_with_the_reason(spec, value, expected):
    with pytest.raises(ValueError) as info:
        coerce(spec, value)
    assert str(info.value).startswith(expected)


def test_check_choices_bounds_step_finite():
    assert check(MODE, 'balance') == ''
    assert check(MODE, 'bogus') == "mode must be one of off, balance, auto, got 'bogus'"
    assert check(GAIN, 0.0) == '' and check(GAIN, -10.0) == ''
    assert check(GAIN, 0.5) == 'gain must be <= 0, got 0.5'
    assert check(GAIN, math.nan) == 'gain must be finite, got nan'
    assert check(COUNT, 0) == 'count must be >= 1, got 0'
    assert check(SIGN, -1) == '' and check(SIGN, 1) == ''
    assert check(SIGN, 0) == 'sign must be -1 + a multiple of 2, got 0'
    open_low = ParamSpec('t', 1.0, 'a time', low=0.0, low_open=True)
    assert check(open_low, 0.0) == 't must be > 0, got 0.0' and check(open_low, 1e-9) == ''
    below = ParamSpec('v', 1.0, 'a speed', low=1.0, high=800.0, high_open=True)
    assert check(below, 800.0) == 'v must be < 800, got 800.0'


def test_describe_texts():
    assert GAIN.range == (-10.0, 0.0) and GAIN.constraint_text() == ''
    assert MODE.range is None and MODE.constraint_text() == 'one of: off, balance, auto'
    t = ParamSpec('t', 1.0, 'a time', low=0.0, low_open=True)
    assert t.range is None and t.constraint_text() == '> 0'
    assert ParamSpec('d', 0.0, 'a delay', low=0.0).constraint_text() == '>= 0'
    v = ParamSpec('v', 1.0, 'a speed', low=1.0, high=800.0, high_open=True, constraints='below the cut-off')
    assert v.range == (1.0, 800.0) and v.constraint_text() == '< 800; below the cut-off'
