"""A node process stopped by SIGINT / SIGTERM (rwpend_ros.runner): its close() still publishes
(the controller's release of the rig, rwpend_ros.claim, is its last command)."""
from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CHILD = r'''
import os, signal, sys, threading
from rclpy.node import Node
from std_msgs.msg import String
from rwpend_ros.runner import run_node

class Closing(Node):
    def __init__(self):
        super().__init__('closing')
        self.pub = self.create_publisher(String, 'said_at_close', 10)
        print('ready', flush=True)

    def close(self):
        self.pub.publish(String(data='bye'))
        print('published at close', flush=True)

sys.exit(run_node(Closing))
'''


@pytest.mark.timeout(120)
@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_close_publishes_after_a_stop_signal(ros_env, sig):
    p = subprocess.Popen([sys.executable, '-c', CHILD], env=ros_env, stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True, cwd=ROOT)
    try:
        assert p.stdout.readline().strip() == 'ready'
        p.send_signal(sig)
        out, _ = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0, out
    assert 'published at close' in out, out
