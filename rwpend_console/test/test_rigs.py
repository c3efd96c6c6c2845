"""Rigs on the console's domains."""
import pytest

from rwpend_console.rigs import node_name, parse_rig_id, rig_id, rig_namespaces


def test_rig_namespaces_from_topics():
    topics = ['/rwpend/encoders', '/rwpend/state', '/rig2/controller/status', '/diagnostics', '/clock',
              '/lab/a/encoders', '/encoders', '/bad-name/encoders']
    assert rig_namespaces(topics) == ['/', '/lab/a', '/rig2', '/rwpend']


def test_rig_ids():
    assert rig_id(60, '/rwpend') == '60:/rwpend'
    assert parse_rig_id('60:/rwpend', [60, 61]) == (60, '/rwpend')
    for bad in ('/rwpend', '60:rwpend', 'x:/a', '60:/a b', None):
        with pytest.raises(ValueError, match='DOMAIN:/NAMESPACE'):
            parse_rig_id(bad, [60])
    with pytest.raises(ValueError, match='does not watch domain 7'):
        parse_rig_id('7:/rwpend', [60])


def test_node_names():
    assert node_name('/rwpend', 'controller') == '/rwpend/controller'
    assert node_name('/', 'sim') == '/sim'
    assert node_name('/rwpend', '/other/estimator') == '/other/estimator'
    for bad in ('', 'a b', '../x', 'controller/'):
        with pytest.raises(ValueError, match='not a node name'):
            node_name('/rwpend', bad)
