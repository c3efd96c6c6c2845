"""The e-stop the console shows is the plant's, decided from its reports on /diagnostics and this
console's own requests: raised by the rig or elsewhere, cleared elsewhere, a request not yet
reported, one the plant did not take, a lost rig."""
import pytest

from rwpend_console.estop import CONFIRM_S, STALE_AFTER_S, EstopTracker


def tracker(*reports):
    """A tracker fed ``(t, plant, value)`` reports and ``(t, 'request', on)`` requests in order."""
    tr = EstopTracker()
    for t, who, what in reports:
        if who == 'request':
            tr.requested(what, t)
        else:
            tr.report(who, what, t)
    return tr


def test_nothing_reported_is_unknown():
    st = EstopTracker().state(10.0)
    assert st.state == 'unknown' and 'no plant' in st.text and st.by == ''


def test_the_plant_says_raised_or_clear_whoever_asked():
    st = tracker((1.0, 'sim', 'False')).state(1.5)
    assert (st.state, st.by, st.pending, st.plants) == ('clear', '', '', ('sim',))
    st = tracker((1.0, 'sim', 'True')).state(1.5)
    assert st.state == 'raised' and 'held at zero' in st.text and st.by == '', 'not seen to change: by nobody known'


def test_raised_by_the_rig_elsewhere_and_cleared_elsewhere():
    tr = tracker((1.0, 'sim', 'False'), (2.0, 'sim', 'True'))      # ./rwpend estop, the ~/estop service
    st = tr.state(2.1)
    assert st.state == 'raised' and st.by == 'elsewhere' and 'elsewhere' in st.text
    tr.report('sim', 'False', 5.0)                                   # ./rwpend estop --clear
    st = tr.state(5.1)
    assert st.state == 'clear' and st.by == 'elsewhere' and 'cleared elsewhere' in st.text


def test_a_raise_from_this_console_then_a_clear_from_elsewhere():
    """The student's case: raised from the page, cleared with ./rwpend estop --clear: the
    console shows clear (it used to keep showing its own raise)."""
    tr = tracker((1.0, 'sim', 'False'), (2.0, 'request', True))
    st = tr.state(2.01)
    assert st.state == 'clear' and st.pending == 'raise' and 'waiting for sim' in st.text
    tr.report('sim', 'True', 2.02)
    st = tr.state(2.1)
    assert (st.state, st.by, st.pending) == ('raised', 'console', '') and 'from this console' in st.text
    tr.report('sim', 'True', 3.0)                                    # the periodic report: no change
    assert tr.state(3.1).by == 'console'
    tr.report('sim', 'False', 10.0)
    st = tr.state(10.1)
    assert (st.state, st.by, st.pending, st.unconfirmed) == ('clear', 'elsewhere', '', False)


def test_a_clear_from_this_console():
    tr = tracker((1.0, 'sim', 'True'), (2.0, 'request', False))
    assert tr.state(2.1).pending == 'clear' and tr.state(2.1).state == 'raised'
    tr.report('sim', 'False', 2.2)
    st = tr.state(2.3)
    assert (st.state, st.by, st.pending) == ('clear', 'console', '') and 'cleared from this console' in st.text


def test_a_report_on_its_way_before_the_request_does_not_undo_it():
    """A periodic report sent just before the plant took the raise arrives after the request:
    still pending, then the change."""
    tr = tracker((1.0, 'sim', 'False'), (2.0, 'request', True), (2.05, 'sim', 'False'))
    assert tr.state(2.1).pending == 'raise'
    tr.report('sim', 'True', 2.1)
    assert tr.state(2.2).state == 'raised' and tr.state(2.2).by == 'console'


def test_a_request_the_plant_did_not_take_is_said():
    tr = tracker((1.0, 'sim', 'False'), (2.0, 'request', True), (2.5, 'sim', 'False'), (3.5, 'sim', 'False'))
    st = tr.state(2.0 + CONFIRM_S + 0.1)
    assert st.state == 'clear' and st.unconfirmed and not st.pending and 'NOT CONFIRMED' in st.text
    tr = tracker((1.0, 'sim', 'True'), (2.0, 'request', False), (3.0, 'sim', 'True'))
    st = tr.state(2.0 + CONFIRM_S + 0.1)
    assert st.state == 'raised' and st.unconfirmed and 'not taken' in st.text


def test_a_raise_when_already_raised_was_raised_before():
    tr = tracker((1.0, 'sim', 'False'), (2.0, 'sim', 'True'), (3.0, 'request', True))
    st = tr.state(3.1)
    assert (st.state, st.by, st.pending, st.unconfirmed) == ('raised', 'elsewhere', '', False)


def test_a_lost_rig_is_unknown_with_what_it_said_last():
    tr = tracker((1.0, 'sim', 'True'))
    st = tr.state(1.0 + STALE_AFTER_S + 2)
    assert st.state == 'unknown' and 'lost the rig' in st.text and 'it said raised' in st.text
    tr.report('sim', 'True', 10.0)
    assert tr.state(10.1).state == 'raised', 'reports again: known again'


def test_any_raised_plant_decides_and_bad_values_are_unknown():
    tr = tracker((1.0, 'sim', 'False'), (1.0, 'driver', 'True'))
    st = tr.state(1.5)
    assert st.state == 'raised' and st.plants == ('driver',)
    st = tracker((1.0, 'sim', None)).state(1.5)
    assert st.state == 'unknown' and 'no e-stop value' in st.text
    st = tracker((1.0, 'sim', 'maybe'), (1.0, 'driver', 'False')).state(1.5)
    assert st.state == 'clear' and st.plants == ('driver',)


def test_as_dict_for_the_page():
    d = tracker((1.0, 'sim', 'False'), (2.0, 'sim', 'True')).state(2.5).as_dict()
    assert d['state'] == 'raised' and d['plants'] == ['sim'] and d['by'] == 'elsewhere'
    assert d['age_s'] == pytest.approx(0.5)


@pytest.mark.parametrize('plant, on', [('', True), (None, True), ('sim', 'yes'), ('sim', 1)])
def test_bad_input_is_refused(plant, on):
    tr = EstopTracker()
    with pytest.raises(ValueError):
        if plant == 'sim':
            tr.requested(on, 1.0)
        else:
            tr.report(plant, 'True', 1.0)
