"""The soak's packet-drop rule is a ruleset nft(8) accepts (checked with ``nft -c``, which changes
nothing; nftables installed as root when missing, else skipped with the reason)."""
from __future__ import annotations

import os
import subprocess

import pytest

from support.netlab import ensure_nft
from rwpend_bench.soak import drop_rule


@pytest.mark.parametrize('share', [0.01, 0.1, 0.5])
def test_the_drop_rule_is_valid_nftables(share):
    # installed here as root when missing (as the network tests do); decided when the test runs,
    # not when the module is imported
    why = 'needs root' if os.geteuid() != 0 else ensure_nft()
    if why:
        pytest.skip(why)
    r = subprocess.run(['nft', '-c', '-f', '-'], input=drop_rule(share), text=True, capture_output=True)
    assert r.returncode == 0, r.stderr


def test_the_drop_rule_drops_the_share_asked():
    assert '< 100 drop' in drop_rule(0.01) and '< 5000 drop' in drop_rule(0.5)
