"""Who may do what: loopback by default, the token elsewhere, the e-stop always."""
import pytest

from rwpend_console.access import (CHANGE, ESTOP, TOKEN_HEADER, VIEW, AccessPolicy, check_token_text,
                                   host_name, is_loopback, new_token)

TOKEN = 'abcdefghijklmnop_1234'
JSON = {'Content-Type': 'application/json'}


def test_tokens():
    t = new_token()
    assert check_token_text(t) == t and len(t) >= 16
    for bad in ('short', 'has space in it 123', 'x' * 200, 5):
        with pytest.raises(ValueError):
            check_token_text(bad)


def test_host_names():
    assert host_name('127.0.0.1:8080') == '127.0.0.1'
    assert host_name('[::1]:8080') == '::1'
    assert host_name('LocalHost') == 'localhost'
    assert is_loopback('127.0.0.2') and is_loopback('::1') and not is_loopback('0.0.0.0')


def test_loopback_console_needs_no_token_but_a_local_host_name():
    p = AccessPolicy('127.0.0.1', TOKEN)
    assert not p.token_required
    assert p.check(VIEW, 'GET', {'Host': '127.0.0.1:8080'}).ok
    assert p.check(CHANGE, 'POST', {'Host': 'localhost:8080', **JSON}).ok
    v = p.check(VIEW, 'GET', {'Host': 'evil.example:8080'})      # DNS rebinding
    assert not v.ok and v.status == 421 and 'this machine only' in v.reason


def test_acting_needs_a_json_post_from_the_console_itself():
    p = AccessPolicy('127.0.0.1', TOKEN)
    host = {'Host': '127.0.0.1:8080'}
    assert p.check(CHANGE, 'GET', host).status == 405
    assert p.check(CHANGE, 'POST', {**host, 'Content-Type': 'text/plain'}).status == 415
    v = p.check(CHANGE, 'POST', {**host, **JSON, 'Origin': 'http://evil.example'})
    assert not v.ok and v.status == 403 and 'another site' in v.reason
    assert p.check(CHANGE, 'POST', {**host, **JSON, 'Origin': 'http://127.0.0.1:8080'}).ok


def test_shared_console_needs_the_token_to_act_not_to_look_or_stop():
    p = AccessPolicy('0.0.0.0', TOKEN)
    assert p.token_required
    host = {'Host': '192.0.2.2:8080', **JSON}
    assert p.check(VIEW, 'GET', {'Host': '192.0.2.2:8080'}).ok
    assert p.check(VIEW, 'POST', host).ok                       # a design preview changes nothing
    v = p.check(CHANGE, 'POST', host)
    assert not v.ok and v.status == 403 and 'token' in v.reason
    assert not p.check(CHANGE, 'POST', {**host, TOKEN_HEADER: TOKEN[:-1] + 'x'}).ok
    assert p.check(CHANGE, 'POST', {**host, TOKEN_HEADER.lower(): TOKEN}).ok
    # the e-stop: no token, any origin, any method
    assert p.check(ESTOP, 'POST', {'Host': 'whatever', 'Origin': 'http://elsewhere'}).ok
    assert AccessPolicy('127.0.0.1', TOKEN).check(ESTOP, 'POST', {'Host': 'evil.example'}).ok


def test_bad_policy_arguments():
    with pytest.raises(ValueError):
        AccessPolicy('somewhere', TOKEN)
    with pytest.raises(ValueError):
        AccessPolicy('127.0.0.1', 'short')
