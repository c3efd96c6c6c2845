"""The console's command line: bad arguments are refused with the reason."""
import pytest

from rwpend_console.console import parser, url


def args(*a):
    return parser().parse_args(list(a))


def test_defaults():
    a = args()
    assert (a.ns, a.port, a.listen, a.rate, a.window, a.no_bridge) == ('/rwpend', 8080, '127.0.0.1', 50.0, 20.0, False)


@pytest.mark.parametrize('argv, why', [
    (['--port', '0'], 'port'), (['--listen', 'everywhere'], '--listen'), (['--rate', '5000'], 'rate'),
    (['--window', '1'], 'window'), (['--domain', '300'], 'domain'), (['--ns', 'a b'], 'namespace'),
    (['--token', 'short'], 'token'),
])
def test_bad_arguments(argv, why, capsys):
    with pytest.raises(SystemExit) as e:
        args(*argv)
    assert e.value.code == 2 and why in capsys.readouterr().err


def test_urls():
    assert url('127.0.0.1', 8080, '0:/rwpend', None) == 'http://127.0.0.1:8080/?rig=0:/rwpend'
    assert url('0.0.0.0', 8080, '3:/rig2', 'tok_tok_tok_tok_1') == \
        'http://127.0.0.1:8080/?rig=3:/rig2&token=tok_tok_tok_tok_1'
