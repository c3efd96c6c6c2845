"""Which Fast DDS transport the rwpend processes use. Pure (no rclpy): it only edits the
environment, and must run before ``rclpy.init`` (Fast DDS reads it when the participant is made).

Why not Fast DDS's shared memory: when a process holding a shared-memory port is SIGKILLed
(a crashed node, a killed monitoring tool), Fast DDS 2.14 can block the *other* processes'
sends towards it for 0.3-3 s (``publish()`` took 1000 then 2000 ms in one measured case; the
simulator and the recorder froze 1-2.8 s in the dead-controller system test, 2 runs in 12
on a loaded machine). On the rig that freezes the driver's loop long enough for the device
watchdog to trip. Over UDP a dead peer costs nothing: no ``publish()`` over 12 ms in 108
kills, against 8 stalls of 0.33-3 s in 168 kills over shared memory (PERFORMANCE.md, "What
each mechanism buys").

``RWPEND_TRANSPORT``:

* ``udp`` (default): UDP only. With ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` (our
  default) rmw_fastrtps would add shared memory itself, so the range is handed to a Fast DDS
  profile instead (``fastdds_udp_localhost.xml``: UDPv4 on 127.0.0.1 only, localhost as the
  initial peer, no multicast), and rmw is told ``SYSTEM_DEFAULT`` so that it leaves the
  transports alone; discovery still stays on this host. With ``SUBNET`` (a lab network): a
  profile too (``fastdds_udp_subnet.xml``: UDPv4, socket buffers of 4 MB; the file says why),
  discovery as rmw_fastrtps does it for that range.
* ``shm``: rmw_fastrtps's defaults (shared memory + UDP).

Nothing is changed when the user configures Fast DDS already (a profiles file,
``FASTDDS_BUILTIN_TRANSPORTS``), sets ``ROS_STATIC_PEERS`` with the localhost range, or uses
another RMW. Processes with either setting talk to each other (over UDP).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Mapping, MutableMapping

PROFILE = Path(__file__).resolve().parent / 'fastdds_udp_localhost.xml'
SUBNET_PROFILE = Path(__file__).resolve().parent / 'fastdds_udp_subnet.xml'
CHOICES = ('udp', 'shm')


def transport_choice(env: Mapping[str, str] | None = None) -> str:
    """``RWPEND_TRANSPORT`` as given (``udp`` when unset); ValueError when unknown."""
    env = os.environ if env is None else env
    choice = env.get('RWPEND_TRANSPORT', 'udp').strip().lower() or 'udp'
    if choice not in CHOICES:
        raise ValueError(f"RWPEND_TRANSPORT={env['RWPEND_TRANSPORT']!r}: expected one of {', '.join(CHOICES)}")
    return choice


def apply_transport(env: MutableMapping[str, str] | None = None) -> str:
    """Edit ``env`` (default os.environ) for ``RWPEND_TRANSPORT``; returns what was done, for
    the log. Raises ValueError on an unknown ``RWPEND_TRANSPORT``."""
    env = os.environ if env is None else env
    if transport_choice(env) == 'shm':
        return 'shm: rmw_fastrtps defaults (shared memory + UDP)'
    if env.get('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp') != 'rmw_fastrtps_cpp':
        return f"left to {env['RMW_IMPLEMENTATION']}"
    for var in ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE', 'FASTDDS_BUILTIN_TRANSPORTS'):
        if env.get(var):
            return f'left to {var}={env[var]}'
    rng = env.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '').strip().upper()
    if rng == 'LOCALHOST':
        if env.get('ROS_STATIC_PEERS', '').strip():
            return 'left to rmw_fastrtps (ROS_STATIC_PEERS with the LOCALHOST range)'
        env['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(PROFILE)
        env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'SYSTEM_DEFAULT'
        env['RWPEND_DISCOVERY_RANGE'] = 'LOCALHOST'   # what the user asked for (for messages)
        return 'udp on localhost (Fast DDS profile)'
    if rng in ('', 'SUBNET'):
        env['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(SUBNET_PROFILE)
        return 'udp on the subnet (Fast DDS profile)'
    return f'left to rmw_fastrtps (discovery range {rng})'


def apply_transport_or_exit(env: MutableMapping[str, str] | None = None) -> str:
    """:func:`apply_transport` for a process's entry point: a bad ``RWPEND_TRANSPORT`` is
    reported on stderr and ends the process with status 2 (no traceback)."""
    try:
        return apply_transport(env)
    except ValueError as exc:
        print(f'error: {exc}', file=sys.stderr, flush=True)
        raise SystemExit(2) from None


def discovery_range(env: MutableMapping[str, str] | None = None) -> str:
    """The discovery range the user asked for (before :func:`apply_transport` rewrote it)."""
    env = os.environ if env is None else env
    return env.get('RWPEND_DISCOVERY_RANGE') or env.get('ROS_AUTOMATIC_DISCOVERY_RANGE') or 'SUBNET'
