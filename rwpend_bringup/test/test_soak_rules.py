"""The soak's packet-drop rule is a ruleset nft(8) accepts (checked with ``nft -c``, which changes
nothing; skipped where nft or the privilege is missing)."""
from __future__ import annotations

import os
import shutil
import subprocess

import pytest

from rwpend_bringup.soak import drop_rule


@pytest.mark.skipif(shutil.which('nft') is None or os.geteuid() != 0, reason='needs nft(8) and root')
@pytest.mark.parametrize('share', [0.01, 0.1, 0.5])
def test_the_drop_rule_is_valid_nftables(share):
    r = subprocess.run(['nft', '-c', '-f', '-'], input=drop_rule(share), text=True, capture_output=True)
    assert r.returncode == 0, r.stderr


def test_the_drop_rule_drops_the_share_asked():
    assert '< 100 drop' in drop_rule(0.01) and '< 5000 drop' in drop_rule(0.5)
