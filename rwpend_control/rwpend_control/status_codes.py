"""The enumerated codes of ``controller/status`` (rwpend_msgs/ControllerStatus), pure (no rclpy).

``switch_code`` says why the last change of mode or law happened, ``fault_code`` what forces
u = 0 on a sample; ``reason`` and ``fault`` say the same for people. The values are the
message's constants (``SWITCH_*``, ``FAULT_*`` in ``ControllerStatus.msg``, read from the
installed .msg file: the one source). :mod:`rwpend_control.supervisor` sets a code wherever it
sets a text; whoever reads controller/status (the node's log and diagnostics, the lab's run data,
the identification) judges by the code, never by the text.
"""
from __future__ import annotations

from rwpend_ros.msglayout import constants

_CODES = constants('rwpend_msgs/msg/ControllerStatus')

SWITCH_START = _CODES['SWITCH_START']
SWITCH_SET_MODE = _CODES['SWITCH_SET_MODE']
SWITCH_CATCH = _CODES['SWITCH_CATCH']
SWITCH_FALL = _CODES['SWITCH_FALL']
SWITCH_FELL = _CODES['SWITCH_FELL']
SWITCH_OVERSPEED = _CODES['SWITCH_OVERSPEED']
SWITCH_WHEEL_STOPPED = _CODES['SWITCH_WHEEL_STOPPED']
SWITCH_WHEEL_BRAKED = _CODES['SWITCH_WHEEL_BRAKED']
SWITCH_SATURATED = _CODES['SWITCH_SATURATED']
SWITCH_FRESH_START = _CODES['SWITCH_FRESH_START']
SWITCH_LAW_FAULT = _CODES['SWITCH_LAW_FAULT']
SWITCH_ESTOP_RAISED = _CODES['SWITCH_ESTOP_RAISED']
SWITCH_ESTOP_CLEARED = _CODES['SWITCH_ESTOP_CLEARED']

FAULT_NONE = _CODES['FAULT_NONE']
FAULT_STALE_STATE = _CODES['FAULT_STALE_STATE']
FAULT_BAD_STATE = _CODES['FAULT_BAD_STATE']
FAULT_OUT_OF_ORDER = _CODES['FAULT_OUT_OF_ORDER']
FAULT_LAW = _CODES['FAULT_LAW']
FAULT_INTERNAL = _CODES['FAULT_INTERNAL']

#: The switches the safety checks make (rwpend_control.safety): logged as warnings, and a WARN
#: on /diagnostics while they hold.
SAFETY_SWITCHES = frozenset({SWITCH_OVERSPEED, SWITCH_SATURATED, SWITCH_FELL})
#: The loop's faults: the state did not come in time or was implausible -- the estimator's
#: output or its delivery, not the law.
LOOP_FAULTS = frozenset({FAULT_STALE_STATE, FAULT_BAD_STATE})


def code_name(code: int, kind: str = 'FAULT') -> str:
    """The constant's name of a code, for people: ``code_name(1)`` -> ``'FAULT_STALE_STATE'``
    (``kind``: 'FAULT' or 'SWITCH'); ``'<kind> <code>'`` for a code the .msg does not have."""
    for name, value in _CODES.items():
        if name.startswith(kind + '_') and value == code:
            return name
    return f'{kind} {code}'
