"""Shared fixtures of the system tests: an isolated ROS 2 environment per test."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from rwpend_ros.testenv import test_domain_id

ROOT = Path(__file__).resolve().parents[1]
PY = str(ROOT / '.venv' / 'bin' / 'python') if (ROOT / '.venv' / 'bin' / 'python').exists() else sys.executable


@pytest.fixture
def ros_env():
    """Environment for node processes: own ROS_DOMAIN_ID (100-230), discovery on localhost only."""
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(test_domain_id())
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['RMW_IMPLEMENTATION'] = env.get('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
    env['PYTHONUNBUFFERED'] = '1'
    return env


@pytest.fixture
def netlab(tmp_path):
    """Test hosts in network namespaces (tests/support/netlab.py), deleted at the end of the test;
    the test is skipped, with the reason, where they cannot be made (not root, no ip(8))."""
    from support.netlab import NetLab, why_not_available
    reason = why_not_available()
    if reason is not None:
        pytest.skip(f'no test hosts in network namespaces: {reason}')
    lab = NetLab(log_dir=tmp_path / 'lab')
    try:
        yield lab
    finally:
        lab.close()


@pytest.fixture
def lab_env():
    """Environment of processes on the test hosts: a test domain id, discovery on the subnet."""
    from support.netrun import lab_env as make
    return make(test_domain_id())
