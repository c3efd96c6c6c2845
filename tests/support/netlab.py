"""Test hosts in Linux network namespaces: a small lab network on one machine (needs root).

Each host is a network namespace with one interface ``eth0`` (10.77.0.N/24) on an Ethernet
switch: a Linux bridge in a namespace of its own, so nothing of the lab touches the machine's
own network. Processes started with :meth:`NetLab.popen` run "on" a host: DDS there sees only
the lab's subnet (``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``), exactly as on separate PCs of one
lab subnet; abstract Unix sockets and anything else scoped to a network namespace do not cross
hosts. Shared memory (``/dev/shm``) and the clock are those of the machine.

Faults of a host's link, at the switch (the cable between the host and the switch):

* :meth:`NetLab.cut` / :meth:`NetLab.restore` -- the switch port down / up (``ip link set``);
* :meth:`NetLab.set_loss` -- random loss of the host's UDP datagrams, both ways, with nftables
  (``numgen random``) in the host's namespace; needs the ``nft`` tool;
* delay -- this kernel has no ``netem`` qdisc, so a host made with ``delay_ms`` is wired to its
  switch port through :mod:`support.delayline` (tests/support/delayline.py), a userspace delay line that holds every
  Ethernet frame for the delay, both ways (:meth:`NetLab.set_delay` changes it while it runs).

Every name the lab creates starts with its ``prefix`` (``rwl<pid>x<random>``), so labs of
several test runs on one machine never meet; :meth:`NetLab.close` (also the context manager's
exit) stops the lab's processes and deletes its namespaces, which deletes their interfaces.

    with NetLab() as lab:
        a, b = lab.add_host('a'), lab.add_host('b')
        p = lab.popen(a, ['./rwpend', 'up', ...], env=env)
        lab.cut(b); ...; lab.restore(b)

Pure Python (subprocess + ``ip``), no rclpy.
"""
from __future__ import annotations

import json
import os
import secrets
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

SUBNET = '10.77.0'


class NetLabError(RuntimeError):
    """The lab could not be built (not root, no ``ip``, no namespaces): the reason."""


def why_not_available() -> str | None:
    """None when network namespaces can be made here, else the reason (for a test's skip)."""
    if sys.platform != 'linux':
        return f'network namespaces need Linux (this is {sys.platform})'
    if os.geteuid() != 0:
        return 'creating network namespaces needs root (ip netns add); run the tests as root'
    if shutil.which('ip') is None:
        return 'the ip tool (iproute2) is not installed'
    name = f'rwl{os.getpid()}probe{secrets.token_hex(2)}'
    p = subprocess.run(['ip', 'netns', 'add', name], capture_output=True, text=True)
    if p.returncode != 0:
        return f'ip netns add failed: {p.stderr.strip() or p.returncode}'
    subprocess.run(['ip', 'netns', 'del', name], capture_output=True)
    return None


def why_no_nft() -> str | None:
    """None when nftables can drop packets here (the ``nft`` tool), else the reason."""
    if shutil.which('nft') is None:
        return 'the nft tool is not installed (Debian package nftables)'
    return None


def ensure_nft() -> str | None:
    """Install the Debian package nftables when ``nft`` is missing and we are root (the tests'
    set-up); returns the reason when it is still missing."""
    if why_no_nft() is None:
        return None
    if os.geteuid() == 0 and shutil.which('apt-get'):
        subprocess.run(['apt-get', 'install', '-y', '-qq', 'nftables'], capture_output=True,
                       timeout=300, env={**os.environ, 'DEBIAN_FRONTEND': 'noninteractive'})
    return why_no_nft()


@dataclass
class Host:
    """One host of the lab: its namespace, address and switch port."""

    name: str
    netns: str
    ip: str
    port: str                       # its port on the switch (in the switch's namespace)
    delay_ms: float | None = None   # None: wired straight to the switch; else through a delay line
    delayline: subprocess.Popen | None = field(default=None, repr=False)


class NetLab:
    """A switch and hosts in network namespaces; see the module doc."""

    def __init__(self, prefix: str | None = None, log_dir: str | Path | None = None) -> None:
        reason = why_not_available()
        if reason is not None:
            raise NetLabError(reason)
        self.prefix = prefix or f'rwl{os.getpid()}x{secrets.token_hex(2)}'
        self.switch = f'{self.prefix}-sw'
        self.log_dir = Path(log_dir) if log_dir is not None else None
        self.hosts: list[Host] = []
        self.procs: list[subprocess.Popen] = []
        self.namespaces: list[str] = []
        self._netns_add(self.switch)
        self._ip(self.switch, 'link', 'add', 'br0', 'type', 'bridge', 'mcast_snooping', '0',
                 'stp_state', '0', 'forward_delay', '0')
        self._ip(self.switch, 'link', 'set', 'br0', 'up')

    # ---------------------------------------------------------------- building
    def _run(self, *cmd: str) -> str:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=30)
        if p.returncode != 0:
            raise NetLabError(f'{" ".join(cmd)}: {p.stderr.strip() or f"exit {p.returncode}"}')
        return p.stdout

    def _ip(self, netns: str, *args: str) -> str:
        return self._run('ip', '-n', netns, *args)

    def _netns_add(self, name: str) -> None:
        self._run('ip', 'netns', 'add', name)
        self.namespaces.append(name)
        self._ip(name, 'link', 'set', 'lo', 'up')

    def add_host(self, name: str, delay_ms: float | None = None) -> Host:
        """A new host on the switch (``delay_ms``: wired through a delay line, see the module
        doc; 0 is a delay line that adds nothing but its own processing)."""
        if not name.isalnum() or len(name) > 8:
            raise ValueError(f'host name: up to 8 letters or digits, got {name!r}')
        if any(h.name == name for h in self.hosts):
            raise ValueError(f'host {name!r} exists already')
        if delay_ms is not None and not 0 <= delay_ms <= 1000:
            raise ValueError(f'delay_ms must be in 0..1000, got {delay_ms!r}')
        i = len(self.hosts) + 1
        host = Host(name, f'{self.prefix}-{name}', f'{SUBNET}.{i}', f'p{i}', delay_ms)
        self._netns_add(host.netns)
        self._ip(host.netns, 'link', 'add', 'eth0', 'type', 'veth', 'peer', 'name', host.port,
                 'netns', self.switch)
        self._ip(host.netns, 'addr', 'add', f'{host.ip}/24', 'dev', 'eth0')
        self._ip(host.netns, 'link', 'set', 'eth0', 'up')
        # multicast (DDS discovery) leaves by eth0: the host has no default route
        self._ip(host.netns, 'route', 'add', '224.0.0.0/4', 'dev', 'eth0')
        if delay_ms is None:
            self._ip(self.switch, 'link', 'set', host.port, 'master', 'br0')
        else:
            # port -- delay line -- d<i> ~ b<i> -- br0
            self._ip(self.switch, 'link', 'add', f'd{i}', 'type', 'veth', 'peer', 'name', f'b{i}')
            self._ip(self.switch, 'link', 'set', f'b{i}', 'master', 'br0')
            for dev in (f'd{i}', f'b{i}'):
                self._ip(self.switch, 'link', 'set', dev, 'up')
            host.delayline = self._start_delayline(host, f'd{i}')
        self._ip(self.switch, 'link', 'set', host.port, 'up')
        self.hosts.append(host)
        return host

    def _start_delayline(self, host: Host, inner: str) -> subprocess.Popen:
        report = self._log_path(f'delayline_{host.name}.json')
        cmd = ['ip', 'netns', 'exec', self.switch, sys.executable, str(Path(__file__).with_name('delayline.py')),
               host.port, inner, '--delay-ms', repr(float(host.delay_ms))]
        if report is not None:
            cmd += ['--report', str(report)]
        p = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True, start_new_session=True)
        self.procs.append(p)
        line = p.stdout.readline()           # 'ready ...' once both sockets are bound
        if not line.startswith('ready'):
            raise NetLabError(f'delay line of {host.name} did not start: {line.strip()} '
                              f'{p.stdout.read()[-2000:] if p.poll() is not None else ""}')
        return p

    def _log_path(self, name: str) -> Path | None:
        if self.log_dir is None:
            return None
        self.log_dir.mkdir(parents=True, exist_ok=True)
        return self.log_dir / name

    # ---------------------------------------------------------------- running
    def command(self, host: Host, cmd: Sequence[str]) -> list[str]:
        """``cmd`` as run on ``host``."""
        return ['ip', 'netns', 'exec', host.netns, *map(str, cmd)]

    def popen(self, host: Host, cmd: Sequence[str], **kwargs) -> subprocess.Popen:
        """Start ``cmd`` on ``host`` (its own process group); stopped by :meth:`close` if still
        running. ``kwargs`` go to :class:`subprocess.Popen`."""
        kwargs.setdefault('start_new_session', True)
        p = subprocess.Popen(self.command(host, cmd), **kwargs)
        self.procs.append(p)
        return p

    def run(self, host: Host, cmd: Sequence[str], timeout: float = 120, **kwargs) -> subprocess.CompletedProcess:
        """Run ``cmd`` on ``host`` to its end (output captured, text)."""
        return subprocess.run(self.command(host, cmd), capture_output=True, text=True,
                              timeout=timeout, **kwargs)

    # ---------------------------------------------------------------- faults
    def cut(self, host: Host) -> None:
        """Pull the host's cable at the switch: its port down."""
        self._ip(self.switch, 'link', 'set', host.port, 'down')

    def restore(self, host: Host) -> None:
        self._ip(self.switch, 'link', 'set', host.port, 'up')

    def set_loss(self, host: Host, percent: int) -> None:
        """Drop ``percent`` % of the host's UDP datagrams at random, each way (nftables in the
        host's namespace; 0 removes the rule). Needs ``nft`` (:func:`ensure_nft`)."""
        if not (isinstance(percent, int) and 0 <= percent <= 100):
            raise ValueError(f'loss percent must be an integer in 0..100, got {percent!r}')
        reason = why_no_nft()
        if reason is not None:
            raise NetLabError(reason)
        subprocess.run(['ip', 'netns', 'exec', host.netns, 'nft', 'delete', 'table', 'inet', 'rwloss'],
                       capture_output=True)
        if percent == 0:
            return
        rules = ''.join(f'table inet rwloss {{\n  chain {name} {{\n'
                        f'    type filter hook {hook} priority 0; policy accept;\n'
                        f'    meta l4proto udp numgen random mod 100 < {percent} counter drop\n  }}\n}}\n'
                        for name, hook in (('rx', 'input'), ('tx', 'output')))
        p = subprocess.run(['ip', 'netns', 'exec', host.netns, 'nft', '-f', '-'], input=rules,
                           capture_output=True, text=True, timeout=30)
        if p.returncode != 0:
            raise NetLabError(f'nft: {p.stderr.strip()}')

    def loss_counters(self, host: Host) -> dict[str, int]:
        """Datagrams the loss rule dropped so far, {'rx': n, 'tx': n} (empty without a rule)."""
        p = subprocess.run(['ip', 'netns', 'exec', host.netns, 'nft', '-j', 'list', 'table', 'inet',
                            'rwloss'], capture_output=True, text=True)
        if p.returncode != 0:
            return {}
        out: dict[str, int] = {}
        for item in json.loads(p.stdout).get('nftables', []):
            rule = item.get('rule')
            if rule:
                for expr in rule.get('expr', []):
                    if 'counter' in expr:
                        out[rule['chain']] = int(expr['counter']['packets'])
        return out

    def set_delay(self, host: Host, delay_ms: float) -> None:
        """Change the delay of a host made with ``delay_ms`` (frames already held keep theirs)."""
        if host.delayline is None:
            raise NetLabError(f'host {host.name} has no delay line (add_host(..., delay_ms=...))')
        if not 0 <= delay_ms <= 1000:
            raise ValueError(f'delay_ms must be in 0..1000, got {delay_ms!r}')
        host.delayline.stdin.write(f'delay {float(delay_ms)!r}\n')
        host.delayline.stdin.flush()
        host.delay_ms = float(delay_ms)

    def port_counters(self, host: Host) -> dict[str, int]:
        """Packets and bytes through the host's switch port so far (rx: from the host)."""
        base = Path('/sys/class/net')   # read in the switch's namespace
        out = self._run('ip', 'netns', 'exec', self.switch, 'cat',
                        *(str(base / host.port / 'statistics' / f) for f in
                          ('rx_packets', 'rx_bytes', 'tx_packets', 'tx_bytes')))
        keys = ('rx_packets', 'rx_bytes', 'tx_packets', 'tx_bytes')
        return dict(zip(keys, (int(x) for x in out.split())))

    def udp_counters(self, host: Host) -> dict[str, int]:
        """The host's UDP counters (``/proc/net/snmp`` of its namespace): ``InDatagrams``,
        ``RcvbufErrors`` (datagrams dropped because a socket's receive buffer was full), ..."""
        text = self._run('ip', 'netns', 'exec', host.netns, 'cat', '/proc/net/snmp')
        rows = [line.split()[1:] for line in text.splitlines() if line.startswith('Udp:')]
        return dict(zip(rows[0], (int(x) for x in rows[1]))) if len(rows) >= 2 else {}

    # ---------------------------------------------------------------- end
    def close(self) -> None:
        """Stop every process started here (SIGINT, then SIGKILL) and delete the namespaces."""
        for p in self.procs:
            if p.poll() is None:
                try:
                    if p.stdin is not None and not p.stdin.closed and p in self._delaylines():
                        p.stdin.close()      # a delay line ends at the end of its input
                    else:
                        os.killpg(p.pid, signal.SIGINT)
                except (ProcessLookupError, PermissionError, BrokenPipeError):
                    pass
        end = time.monotonic() + 10.0
        for p in self.procs:
            try:
                p.wait(timeout=max(0.1, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                try:
                    os.killpg(p.pid, signal.SIGKILL)
                except (ProcessLookupError, PermissionError):
                    p.kill()
                p.wait(timeout=5)
        self.procs.clear()
        for name in reversed(self.namespaces):
            subprocess.run(['ip', 'netns', 'del', name], capture_output=True)
        self.namespaces.clear()

    def _delaylines(self) -> list[subprocess.Popen]:
        return [h.delayline for h in self.hosts if h.delayline is not None]

    def __enter__(self) -> 'NetLab':
        return self

    def __exit__(self, *exc) -> None:
        self.close()
