"""The mode buttons: every mode of the controller, ``law`` offered only when the controller has a
law file, with the reason (and how to give it one) when it has none."""
import pytest

from rwpend_console.modes import LAW_HOW, MODE_HELP, mode_buttons
from rwpend_control.parameters import MODES


def by_mode(buttons):
    return {b['mode']: b for b in buttons}


def test_every_mode_of_the_controller_has_a_button():
    buttons = mode_buttons(MODES, '')
    assert [b['mode'] for b in buttons] == list(MODES) and 'law' in MODES
    assert set(MODES) <= set(MODE_HELP), 'every mode says what it does'


def test_law_needs_a_law_file():
    law = by_mode(mode_buttons(MODES, ''))['law']
    assert law['usable'] is False and 'law.file' in law['help'] and LAW_HOW in law['help']
    assert all(b['usable'] is True for b in mode_buttons(MODES, '') if b['mode'] != 'law')
    law = by_mode(mode_buttons(MODES, '/home/me/mylaw.py'))['law']
    assert law['usable'] is True and '/home/me/mylaw.py' in law['help']


def test_law_file_unknown_leaves_it_to_the_controller():
    law = by_mode(mode_buttons(MODES, None, 'service /rwpend/controller/get_parameters is not available'))['law']
    assert law['usable'] is None and 'not available' in law['help']


@pytest.mark.parametrize('modes, law_file', [(['off', ''], ''), (['off', 3], ''), (MODES, 5)])
def test_bad_input_is_refused(modes, law_file):
    with pytest.raises(ValueError):
        mode_buttons(modes, law_file)
