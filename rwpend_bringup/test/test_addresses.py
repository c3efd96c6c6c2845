"""Addresses on the command line: --listen, --port and up --console [LISTEN:]PORT."""
import pytest

from rwpend_bringup.addresses import parse_console_address, parse_listen, parse_port


def test_parse_listen_and_port():
    assert parse_listen('localhost') == '127.0.0.1'
    assert parse_listen('0.0.0.0') == '0.0.0.0'
    assert parse_listen('[::1]') == '::1'
    for bad in ('', 'example.org', '300.1.1.1', '0.0.0.0:80'):
        with pytest.raises(ValueError, match='--listen'):
            parse_listen(bad)
    assert parse_port('8080') == 8080
    for bad in ('0', '65536', 'http', '80.5'):
        with pytest.raises(ValueError, match='port'):
            parse_port(bad)


def test_console_addresses():
    assert parse_console_address('8080') == ('127.0.0.1', 8080)
    assert parse_console_address('0.0.0.0:9000') == ('0.0.0.0', 9000)
    assert parse_console_address('[::1]:8081') == ('::1', 8081)
    for bad in ('x', 'host:80', '0.0.0.0:', '70000'):
        with pytest.raises(ValueError, match='--console'):
            parse_console_address(bad)
