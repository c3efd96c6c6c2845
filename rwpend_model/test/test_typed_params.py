"""rwpend_model.rig.typed_like: a read-only parameter's value as its default's type."""
from __future__ import annotations

import array

import pytest

from rwpend_model.rig import typed_like


def test_an_integer_where_a_float_is_expected_is_that_float():
    assert typed_like('start.delay', 0, 0.5) == 0.0 and isinstance(typed_like('x', 2, 0.5), float)
    assert typed_like('taps.times', [1, 2.5], [-1.0]) == [1.0, 2.5]
    assert typed_like('taps.times', array.array('q', [3]), [-1.0]) == [3.0]
    assert typed_like('taps.times', array.array('d', [0.25]), [-1.0]) == [0.25]


def test_values_of_the_right_type_pass_unchanged():
    assert typed_like('baud', 115200, 9600) == 115200
    assert typed_like('pwm', True, False) is True
    assert typed_like('frame_id', 'rig2', 'rwpend') == 'rig2'
    assert typed_like('delay', 0.25, 0.5) == 0.25


@pytest.mark.parametrize('value, default, text', [
    ('abc', 0.5, 'must be a number'),
    (True, 0.5, 'must be a number'),          # a bool is not a number here
    (1.5, 1, 'must be an integer'),
    (True, 1, 'must be an integer'),
    (1, False, 'must be true or false'),
    (5, 'rwpend', 'must be a string'),
    (['x'], [0.0], 'must be a list like [0.0]'),
    ('abc', [0.0], 'must be a list like [0.0]'),
    (3, [0.0], 'must be a list like [0.0]'),
])
def test_other_types_are_refused_naming_the_parameter(value, default, text):
    with pytest.raises(ValueError) as exc:
        typed_like('some.param', value, default)
    assert str(exc.value).startswith('some.param ' + text), str(exc.value)
