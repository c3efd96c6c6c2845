"""The mode buttons (pure: the controller's modes and its law file in, buttons out; no rclpy).

One button per mode the controller takes (:data:`rwpend_control.parameters.MODES`), each with
what it does. Mode ``law`` runs a law of one's own, which the controller loads at start from its
read-only parameter ``law.file`` (:mod:`rwpend_control.controller_node`): without one the
controller refuses the mode, so the button says so and is not offered; when the console cannot
read ``law.file`` the button stays offered and the controller's answer decides.
"""
from __future__ import annotations

from typing import Sequence

#: what each mode does, as the button's help says it (rwpend_control.supervisor)
MODE_HELP = {
    'off': 'u = 0 (a wheel that spins too fast is braked first)',
    'wheel_velocity': 'PI control of the wheel speed to wheel.ref',
    'wheel_angle': 'PD control of the wheel angle to wheel_angle.ref',
    'balance': 'holds the pendulum upright (refused farther than theta_0 from upright)',
    'swingup': 'energy control: swings the pendulum up (no catch)',
    'auto': 'swings up, catches and balances; swings up again after a fall',
    'law': "runs a law of one's own: the controller's law.file",
}
#: how to give the controller a law (the button's reason when it has none)
LAW_HOW = ("start the controller with a law file: ./rwpend up --set controller.law.file=mylaw.py "
           "(a .py file with control(state, params) or a class Law; rwpend_control.user_law)")


def mode_buttons(modes: Sequence[str], law_file: str | None, unknown_reason: str = '') -> list[dict]:
    """[{'mode', 'usable', 'help'}] for ``modes`` in their order; ``law_file``: the controller's
    ``law.file`` ('' none; None: it could not be read, ``unknown_reason`` says why). ``usable``
    is False only for ``law`` without a law file; None when that is not known."""
    if law_file is not None and not isinstance(law_file, str):
        raise ValueError(f'law_file: the text of law.file or None, got {law_file!r}')
    out = []
    for m in modes:
        if not isinstance(m, str) or not m:
            raise ValueError(f'modes: mode names, got {m!r}')
        help_text = MODE_HELP.get(m, '')
        usable: bool | None = True
        if m == 'law':
            if law_file is None:
                usable = None
                help_text = (f"{help_text} (could not read law.file: {unknown_reason or 'no answer'}; "
                             'the controller refuses the mode without one)')
            elif law_file:
                help_text = f"runs the law of {law_file} (the controller's law.file)"
            else:
                usable = False
                help_text = f'needs a law: this controller has no law.file -- {LAW_HOW}'
        out.append({'mode': m, 'usable': usable, 'help': help_text})
    return out
