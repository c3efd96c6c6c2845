"""./rwpend's command table: every command the help lists runs a function of this package or
a 'module:function' of another one, resolved by name when the command runs."""
import re

import pytest

from rwpend_bringup import cli


def test_every_listed_command_is_dispatched():
    listed = set(re.findall(r'^  ([a-z]+)\s', cli.__doc__, re.M)) - {'exec'}   # exec: ./rwpend itself
    assert listed == set(cli.COMMANDS) | set(cli.DELEGATED)
    assert not set(cli.COMMANDS) & set(cli.DELEGATED)


@pytest.mark.parametrize('cmd', sorted(cli.DELEGATED))
def test_delegated_targets_resolve(cmd):
    assert callable(cli.resolve(cli.DELEGATED[cmd]))


def test_a_missing_module_is_not_installed_and_a_broken_one_says_why(tmp_path, monkeypatch):
    with pytest.raises(cli.NotInstalled, match='no_such_package_xyz.cli is not installed'):
        cli.resolve('no_such_package_xyz.cli:main')
    (tmp_path / 'broken_module_xyz.py').write_text('import no_such_dependency_xyz\n')
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ModuleNotFoundError, match='no_such_dependency_xyz'):
        cli.resolve('broken_module_xyz:main')


def test_bag_takes_info_only(capsys):
    assert cli.bag_main([]) == 2 and 'rwpend bag info BAG' in capsys.readouterr().err
