"""The test tiers (the root conftest.py): every collected test has exactly one tier marker, and
the rules give each kind of test its tier."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def load_tiers():
    """The root conftest.py as a module of its own (``conftest`` names whichever was last)."""
    spec = importlib.util.spec_from_file_location('rwpend_test_tiers', ROOT / 'conftest.py')
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


T = load_tiers()


def test_every_collected_test_has_exactly_one_tier(request):
    wrong = [(item.nodeid, names) for item in request.session.items
             if len(names := {m.name for m in item.iter_markers()} & set(T.TIERS)) != 1]
    assert not wrong, wrong


def test_the_tiers_are_the_registered_markers(pytestconfig):
    registered = {line.split(':')[0] for line in pytestconfig.getini('markers')}
    assert set(T.TIERS) <= registered


@pytest.mark.parametrize('path, markers, fixtures, rclpy, tier', [
    ('a/test_x.py', [], ['tmp_path'], False, 'unit'),
    ('a/test_x.py', [], [], True, 'loop'),
    ('a/test_x.py', ['loop', 'parametrize'], [], False, 'loop'),
    ('x/test_x_system.py', [], [], False, 'system'),
    ('x/test_x.py', [], ['ros_env', 'tmp_path'], False, 'system'),
    ('x/test_x_system.py', [], ['browser', 'ros_env'], False, 'browser'),
    ('x/test_x_system.py', [], ['netlab', 'lab_env'], False, 'network'),
    ('x/test_x_system.py', ['network', 'timeout'], [], False, 'network'),
    ('x/test_x_system.py', ['system', 'system'], [], True, 'system'),
    ('x/test_x.py', ['unit'], ['ros_env'], True, 'unit'),
])
def test_rules(path, markers, fixtures, rclpy, tier):
    assert T.tier_of(Path(path), markers, fixtures, rclpy) == tier


@pytest.mark.parametrize('source, starts', [
    ('import math', False),
    ('from rclpy.serialization import serialize_message', False),
    ("'''rclpy.init() in a docstring'''  # and rclpy.init() in a comment", False),
    ('import rclpy\ndef f():\n    ctx = rclpy.Context()\n    rclpy.init(context=ctx)', True),
])
def test_calls_rclpy_init(source, starts):
    assert T.calls_rclpy_init(source) is starts


def test_several_tiers_are_refused():
    with pytest.raises(ValueError, match='several tiers: loop, system'):
        T.tier_of(Path('x/test_x_system.py'), ['system', 'loop'], [], False)


class FakeItem:
    def __init__(self, path, markers=(), fixtures=()):
        self.path, self.nodeid, self.fixturenames = path, f'{path.name}::t', list(fixtures)
        self.markers = [getattr(pytest.mark, m).mark for m in markers]

    def iter_markers(self):
        return iter(self.markers)

    def add_marker(self, mark):
        self.markers.append(mark.mark)


def test_the_hook_marks_each_test_once_and_stops_at_several_tiers(tmp_path):
    f = tmp_path / 'test_x.py'
    f.write_text('rclpy.init()\n')
    items = [FakeItem(f), FakeItem(f, ['system']), FakeItem(f, ['unit'], ['ros_env'])]
    T.pytest_collection_modifyitems(None, items)
    assert [[m.name for m in i.markers] for i in items] == [['loop'], ['system'], ['unit']]
    with pytest.raises(pytest.UsageError, match=r'test_x.py::t: several tiers: loop, unit'):
        T.pytest_collection_modifyitems(None, [FakeItem(f), FakeItem(f, ['unit', 'loop'])])
