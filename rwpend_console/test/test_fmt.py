"""How the console writes numbers: significant digits without raw float tails, signals with
subnormal leftovers as exactly 0, parameter values whole (the page's script follows the same
EXAMPLES: checked in Chromium by tests/test_console_system.py)."""
import math

import pytest

from rwpend_console.fmt import (EXAMPLES, SIGNAL_EXAMPLES, SIGNAL_ZERO, clean_signal, number_text, signal_text,
                                value_text)


@pytest.mark.parametrize('v, digits, text', EXAMPLES)
def test_number_text_examples(v, digits, text):
    assert number_text(v, digits) == text


@pytest.mark.parametrize('v, text', SIGNAL_EXAMPLES)
def test_signal_text_examples(v, text):
    assert signal_text(v) == text


def test_integers_exactly_and_non_finite_by_name():
    assert number_text(1000000) == '1000000' and number_text(-7) == '-7'
    assert number_text(2**63 - 1) == str(2**63 - 1), 'an integer bound is never rounded'
    assert (number_text(math.nan), number_text(math.inf), number_text(-math.inf)) == ('NaN', '∞', '-∞')


def test_a_raw_float_never_shows_its_tail():
    for v in (0.1 + 0.2, 183.72549019607843, 2 / 3, -1e-7 / 3, 1e300 / 7):
        text = number_text(v)
        assert len(text.split('e')[0].replace('-', '').replace('.', '').lstrip('0')) <= 6, text
        assert math.isclose(float(text), v, rel_tol=5e-6), (text, v)


def test_the_motor_lag_leftovers_are_zero():
    for v in (5e-324, -5e-324, 1e-300, -0.0, SIGNAL_ZERO / 2):
        assert clean_signal(v) == 0.0 and math.copysign(1.0, clean_signal(v)) == 1.0
        assert signal_text(v) == '0'
    assert clean_signal(SIGNAL_ZERO) == SIGNAL_ZERO, 'from 1e-9 on a value is shown as it is'
    assert clean_signal(-10.0) == -10.0 and math.isnan(clean_signal(math.nan))


@pytest.mark.parametrize('bad', ['1.0', None, True, [1.0]])
def test_bad_input_is_refused(bad):
    with pytest.raises(TypeError, match='a number'):
        number_text(bad)
    with pytest.raises(TypeError, match='a number'):
        clean_signal(bad)


@pytest.mark.parametrize('digits', [0, 18, 2.5, True])
def test_bad_digits_are_refused(digits):
    with pytest.raises(ValueError, match='digits'):
        number_text(1.0, digits)


def test_value_text_is_the_whole_value():
    assert value_text('double', -312.34567891234567) == '-312.34567891234565'
    assert float(value_text('double', 0.1 + 0.2)) == 0.1 + 0.2, 'reads back as the same double'
    assert value_text('double', 3) == '3.0' and value_text('integer', 10) == '10'
    assert value_text('bool', True) == 'true' and value_text('bool', False) == 'false'
    assert value_text('string', '1.5wp') == '1.5wp' and value_text('not_set', None) == ''
    assert value_text('double_array', [1.0, 2.5]) == '[1.0, 2.5]' and value_text('string_array', ['a']) == '["a"]'
