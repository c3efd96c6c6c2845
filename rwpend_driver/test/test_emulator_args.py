"""`rwpend emulate` arguments: bad values are refused before anything starts."""
import pytest

from rwpend_driver.emulator import parse_args


def test_rt_priority_default_and_range():
    assert parse_args([]).rt_priority == 0
    assert parse_args(['--rt-priority', '60']).rt_priority == 60
    for bad in ('-1', '100', 'high'):
        with pytest.raises(SystemExit):
            parse_args(['--rt-priority', bad])
