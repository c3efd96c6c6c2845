"""The app's requests that read a node (a stand-in watcher answers the parameter services): the
mode buttons from the controller's law.file, a parameter set answered with its whole value."""
import pytest

pytest.importorskip('rcl_interfaces')

from rcl_interfaces.msg import ParameterValue, SetParametersResult  # noqa: E402
from rcl_interfaces.srv import DescribeParameters, GetParameters, SetParameters  # noqa: E402
from rcl_interfaces.msg import ParameterDescriptor, FloatingPointRange  # noqa: E402

from rwpend_console.app import ConsoleApp  # noqa: E402
from rwpend_console.rosside import CallError  # noqa: E402


class Watcher:
    """Answers get/describe/set_parameters of /rwpend/controller from ``values``."""

    domain = 0

    def __init__(self, values, up=True):
        self.values, self.up, self.calls = values, up, []

    def call(self, srv, name, request, timeout=5.0):
        self.calls.append(name)
        if not self.up:
            raise CallError(f'service {name} is not available (is the rig running, on domain 0?)')
        if srv is GetParameters:
            out = GetParameters.Response()
            for n in request.names:
                v = self.values.get(n)
                out.values.append(ParameterValue() if v is None else
                                  ParameterValue(type=4, string_value=v) if isinstance(v, str) else
                                  ParameterValue(type=3, double_value=v))
            return out
        if srv is DescribeParameters:
            return DescribeParameters.Response(descriptors=[ParameterDescriptor(
                name=n, type=3, floating_point_range=[FloatingPointRange(from_value=-1000.0, to_value=0.0)])
                for n in request.names])
        if srv is SetParameters:
            for p in request.parameters:
                self.values[p.name] = p.value.double_value
            return SetParameters.Response(results=[SetParametersResult(successful=True)] * len(request.parameters))
        raise AssertionError(srv)


def app_of(w, tmp_path):
    return ConsoleApp({0: w}, tmp_path, 20.0)


def test_law_is_offered_with_a_law_file_only(tmp_path):
    modes = {m['mode']: m for m in app_of(Watcher({'law.file': ''}), tmp_path).modes('0:/rwpend')['modes']}
    assert modes['law']['usable'] is False and 'law.file' in modes['law']['help']
    assert modes['auto']['usable'] is True
    got = app_of(Watcher({'law.file': '/tmp/mylaw.py'}), tmp_path).modes('0:/rwpend')
    assert got['law_file'] == '/tmp/mylaw.py' and got['modes'][-1] == {
        'mode': 'law', 'usable': True, 'help': "runs the law of /tmp/mylaw.py (the controller's law.file)"}
    gone = app_of(Watcher({}, up=False), tmp_path).modes('0:/rwpend')
    assert gone['law_file'] is None and gone['modes'][-1]['usable'] is None
    assert 'not available' in gone['modes'][-1]['help']


def test_a_set_answers_the_whole_value(tmp_path):
    w = Watcher({'balance.kpp': -300.0})
    r = app_of(w, tmp_path).set_param({'rig': '0:/rwpend', 'node': 'controller', 'name': 'balance.kpp',
                                        'value': '-312.34567891234567'})
    assert r['ok'] and r['value_text'] == '-312.34567891234565'
    r = app_of(w, tmp_path).set_param({'rig': '0:/rwpend', 'node': 'controller', 'name': 'balance.kpp',
                                        'value': '5'})
    assert not r['ok'] and 'must be <= 0' in r['reason'] and r['value_text'] == '-312.34567891234565'
