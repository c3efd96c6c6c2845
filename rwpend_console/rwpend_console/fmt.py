"""How the console writes numbers (pure: numbers in, text out; no rclpy).

* :func:`number_text` -- a number in at most ``digits`` significant digits (6: as the nodes
  write bounds in their messages, ``:g``), without trailing zeros; plain notation for
  1e-4 <= |v| < 10^digits, otherwise ``1.5e-7`` / ``2e6`` (no '+', no leading zero in the
  exponent); an integer exactly; ``-0`` as ``0``; ``NaN``, ``∞``, ``-∞``.
* :func:`clean_signal` / :func:`signal_text` -- a signal (u, the applied command) with
  |v| < :data:`SIGNAL_ZERO` as exactly 0: the motor's current lag decays towards zero through
  subnormal numbers (``5e-324``) that say nothing but "zero" to a reader.
* :func:`value_text` -- a parameter's whole value as its field shows it: never cut (a double in
  the shortest text that reads back as the same double).

The page's script writes the live readouts itself (``rwpendFormat.number`` in
``static/console.js``, 30 times a second); :data:`EXAMPLES` is the contract both follow,
checked on this module by the unit tests and on the script in Chromium by the system test.
"""
from __future__ import annotations

import json
import math
from typing import Any

#: a signal smaller than this (control units) is shown, and plotted, as exactly 0
SIGNAL_ZERO = 1e-9

#: (value, digits, text): what :func:`number_text` and the page's ``rwpendFormat.number`` write
#: (values a JSON number carries alike to both: no integers beyond 2^53, no ties in rounding)
EXAMPLES = (
    (0.0, 6, '0'), (-0.0, 6, '0'), (1.0, 6, '1'), (-300.0, 6, '-300'), (0.1, 6, '0.1'),
    (0.30000000000000004, 6, '0.3'), (183.72549019607843, 6, '183.725'), (-282.123456789, 6, '-282.123'),
    (3.141592653589793, 4, '3.142'), (9.9999996, 6, '10'), (0.0001, 6, '0.0001'),
    (0.000123456789, 6, '0.000123457'), (1e-05, 6, '1e-5'), (1.5e-07, 6, '1.5e-7'),
    (5e-324, 6, '4.94066e-324'), (999999.0, 6, '999999'), (1000000.0, 6, '1e6'),
    (1234567.0, 6, '1.23457e6'), (-2.5e10, 6, '-2.5e10'), (12.51, 2, '13'), (12.49, 2, '12'), (12.5, 3, '12.5'),
)
#: (value, text): what :func:`signal_text` and the page's ``rwpendFormat.signal`` write
SIGNAL_EXAMPLES = (
    (5e-324, '0'), (-5e-324, '0'), (-9.9e-10, '0'), (1e-9, '1e-9'), (0.0, '0'), (10.0, '10'),
    (-9.87654, '-9.877'), (0.0123456, '0.01235'),
)


def _finite_number(v: Any, what: str) -> float | int:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise TypeError(f'{what}: a number, got {v!r}')
    return v


def number_text(v: float | int, digits: int = 6) -> str:
    """``v`` in at most ``digits`` (1..17) significant digits (module docstring)."""
    _finite_number(v, 'number_text')
    if isinstance(digits, bool) or not isinstance(digits, int) or not 1 <= digits <= 17:
        raise ValueError(f'digits: an integer in 1..17, got {digits!r}')
    if isinstance(v, int):
        return str(v)
    if math.isnan(v):
        return 'NaN'
    if math.isinf(v):
        return '∞' if v > 0 else '-∞'
    if v == 0.0:
        return '0'
    mantissa, _, exp = f'{v:.{digits - 1}e}'.partition('e')
    e = int(exp)
    if -4 <= e < digits:
        text = f'{v:.{max(0, digits - 1 - e)}f}'
        return text.rstrip('0').rstrip('.') if '.' in text else text
    if '.' in mantissa:
        mantissa = mantissa.rstrip('0').rstrip('.')
    return f'{mantissa}e{e}'


def clean_signal(v: float) -> float:
    """``v`` with |v| < SIGNAL_ZERO (and -0) as 0.0; NaN and infinities as they are."""
    _finite_number(v, 'clean_signal')
    return 0.0 if abs(v) < SIGNAL_ZERO else float(v)


def signal_text(v: float, digits: int = 4) -> str:
    """A signal's readout: :func:`number_text` of :func:`clean_signal`."""
    return number_text(clean_signal(v), digits)


def value_text(type_name: str, value: Any) -> str:
    """The whole value of a parameter of type ``type_name`` (panel.TYPE_NAMES) as its field
    shows it: a double in its shortest exact text (``repr``), an array as JSON, a bool as
    ``true``/``false``; '' for a parameter without a value."""
    if value is None:
        return ''
    if type_name == 'bool':
        return 'true' if value else 'false'
    if type_name == 'double':
        return repr(float(value))
    if type_name.endswith('_array') or isinstance(value, (list, tuple)):
        return json.dumps(list(value))
    return str(value)
