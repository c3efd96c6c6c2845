"""Test tiers: every collected test gets exactly one of the markers in :data:`TIERS`.

The first rule that applies decides (:func:`tier_of`):

1. a tier marker on the test itself (a decorator, or a module's ``pytestmark``);
2. ``browser`` if it takes the ``browser`` fixture (Chromium, the console's page tests);
3. ``network`` if it takes the ``netlab`` fixture (test hosts in network namespaces);
4. ``system`` if its file is named ``*_system.py`` or it takes ``ros_env`` or ``lab_env`` (the
   environments of node processes);
5. ``loop`` if its module starts rclpy in the test's process (calls ``rclpy.init``);
6. ``unit`` otherwise.

A test with several tier markers of its own stops the collection with the tests named.
``make test-fast`` runs ``-m "unit or loop"``.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

#: the tiers (pytest.ini says what each one's tests do)
TIERS = ('unit', 'loop', 'system', 'network', 'browser')
#: fixtures that make a test system: the environment of node processes (tests/conftest.py)
SYSTEM_FIXTURES = frozenset({'ros_env', 'lab_env'})


def explicit_tiers(markers) -> set[str]:
    """The tier names among the markers' names."""
    return {m for m in markers if m in TIERS}


def calls_rclpy_init(source: str) -> bool:
    """Whether the module's code calls ``rclpy.init`` (a call, not a mention in a string)."""
    for node in ast.walk(ast.parse(source)):
        if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == 'init'
                and isinstance(node.func.value, ast.Name) and node.func.value.id == 'rclpy'):
            return True
    return False


def tier_of(path: Path, markers, fixtures, starts_rclpy: bool) -> str:
    """The tier of a test in file ``path`` with its own ``markers`` (names), the ``fixtures``
    it takes and whether its module ``starts_rclpy`` (the rules of this module's docstring).
    Raises ValueError for several tier markers."""
    own = explicit_tiers(markers)
    if len(own) > 1:
        raise ValueError(f'several tiers: {", ".join(sorted(own))}')
    if own:
        return own.pop()
    if 'browser' in fixtures:
        return 'browser'
    if 'netlab' in fixtures:
        return 'network'
    if path.name.endswith('_system.py') or SYSTEM_FIXTURES & set(fixtures):
        return 'system'
    if starts_rclpy:
        return 'loop'
    return 'unit'


def pytest_collection_modifyitems(config, items):
    """Mark every test with its tier; a test with several tier markers is a usage error."""
    starts_rclpy: dict[Path, bool] = {}
    wrong = []
    for item in items:
        path = Path(str(item.path))
        if path not in starts_rclpy:
            starts_rclpy[path] = path.suffix == '.py' and calls_rclpy_init(path.read_text(encoding='utf-8'))
        markers = [m.name for m in item.iter_markers()]
        try:
            tier = tier_of(path, markers, getattr(item, 'fixturenames', ()), starts_rclpy[path])
        except ValueError as exc:
            wrong.append(f'{item.nodeid}: {exc}')
            continue
        if tier not in markers:
            item.add_marker(getattr(pytest.mark, tier))
    if wrong:
        raise pytest.UsageError('a test has exactly one tier marker (' + ', '.join(TIERS) + '):\n  '
                                + '\n  '.join(wrong))
