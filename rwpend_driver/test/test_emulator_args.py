"""`rwpend emulate` arguments: bad values are refused before anything starts."""
import pytest

from rwpend_driver.emulator import parse_args


def test_rt_priority_default_and_range():
    assert parse_args([]).rt_priority == 0
    assert parse_args(['--rt-priority', '60']).rt_priority == 60
    for bad in ('-1', '100', 'high'):
        with pytest.raises(SystemExit):
            parse_args(['--rt-priority', bad])


def test_link_in_a_missing_directory_is_refused(tmp_path):
    with pytest.raises(SystemExit):
        parse_args(['--link', str(tmp_path / 'nowhere' / 'rig')])


def test_sample_period_option():
    assert parse_args([]).h is None and parse_args(['--h', '0.002']).h == 0.002
    for bad in ('0', '-0.001', '5', 'nan'):
        with pytest.raises(SystemExit):
            parse_args(['--h', bad])
