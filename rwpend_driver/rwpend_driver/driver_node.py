"""``driver`` node: the real rig (or the emulator) over a serial port, with the simulator's topics.

Publishes ``encoders`` (EncoderCounts: seq = monotone sample counter, header.stamp = receive
time) and, for every sample, ``applied`` (AppliedCommand: the command the device held over the
interval that ended at that sample, from its SAMPLE frame -- what the motor got, beside what the
controller sent), subscribes ``command`` (MotorCommand), publishes ``/diagnostics``.  Managed lifecycle
(rclpy.lifecycle): configure = open the port and handshake; activate = enable the amplifier and
publish; deactivate = zero torque, amplifier off; cleanup = close.  ``autostart`` (default
true) configures and activates at start (retrying configure while the device is absent).

Latched e-stop, as on the simulator: topic ``estop`` (std_msgs/Bool, transient local) and
service ``~/estop`` (std_srvs/SetBool; ``./rwpend estop [--clear]``).  Raised, it zeros the
motor and disables the amplifier at once (a zero command, then ENABLE 0), refuses every
command, and holds so -- across reconnections and lifecycle transitions -- until it is
explicitly cleared; cleared, the amplifier is enabled again and the torque stays zero until a
fresh command arrives.  Encoders keep streaming throughout.

Threads: the link thread (started at configure) waits for the port's bytes and publishes each
sample as wire bytes (rwpend_ros.wire) the moment it is read; the executor's thread (rclpy's
EventsExecutor, like every node of the stack) takes the commands and writes each to the port
at once. Neither ever waits for the port (rwpend_driver.port).

Hosted in the loop's process (``rwpend_loop.rig``, the default layout of ``./rwpend up --plant
serial:PORT``): the link thread is the loop's thread. Each SAMPLE frame, as it is read, goes
through :attr:`loop_hook` -- estimate, control, the claim, the COMMAND frame written -- as plain
calls holding the loop's lock, and only then is anything published. A command from the
``command`` topic (a controller in another process) still comes through the same claim.

``/diagnostics``: the link's state and counters, and its health over the last window
(rwpend_driver.link_health: samples lost or taken late, frames the device refused or could not send,
frames the port could not take, watchdog trips, commands refused as old): WARN or ERROR with
what was seen, and a warning in the log with what to do (once per kind every
``health_log_period`` s).

All protocol and link logic lives in :mod:`rwpend_driver.link`, :mod:`rwpend_driver.protocol`,
:mod:`rwpend_driver.port` and :mod:`rwpend_driver.link_health`.
"""
from __future__ import annotations

import contextlib
import struct
import sys
import threading
import time
from functools import partial

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from std_msgs.msg import Bool
from std_srvs.srv import SetBool

from rwpend_msgs.msg import AppliedCommand, EncoderCounts, MotorCommand
from rwpend_ros import wire
from rwpend_ros.claim import CommandClaim, format_id
from rwpend_ros.diagnostics import publish_diagnostic
from rwpend_ros.health import EXIT_LOOP_DEAD, LoopHealth
from rwpend_ros.nodes import SlackTimer, estop_subscriptions, local_subscription
from rwpend_ros.params import ConfigError, ParameterTable, declare_rig
from rwpend_ros.paramspec import ParamSpec
from rwpend_ros.qos import QOS_CONTROL, QOS_CONTROL_PUB, QOS_LATCHED, QOS_STATUS
from rwpend_ros.runner import run_node
from rwpend_ros.sched import raise_thread_priority, thread_priority_spec
from rwpend_ros.trace import tracer

from . import link_health
from . import protocol as P
from .link import MASK32, DriverLink, LinkConfig
from .port import absent_port_hint, serial_ports_present

RO = partial(ParamSpec, read_only=True)
#: s between the lines that say the driver is still waiting for its rig (autostart retrying)
RETRY_NOTE_S = 30.0

#: The driver's parameters, all read-only (set at start): name, default, description, bounds
#: (those of :meth:`rwpend_driver.link.LinkConfig.errors`, which judges them again).
PARAMS = [
    thread_priority_spec(),
    RO('port', '', 'serial device of the rig (e.g. /dev/ttyACM0, or the emulator\'s --link path)',
       constraints='not empty'),
    RO('baud', 921600, 'baud rate (ignored by USB CDC and ptys)', low=1200, high=12_000_000),
    RO('counts_per_rev', 0, 'encoder counts per revolution, checked against what the device reports '
       '(0 = rig.counts_per_rev of the rig YAML, the single source of truth)', low=0, high=MASK32),
    RO('pendulum_sign', 1, 'direction sign of the pendulum encoder (+1 or -1)', low=-1, high=1, step=2),
    RO('motor_sign', 1, 'direction sign of the motor: its encoder and its command (+1 or -1)',
       low=-1, high=1, step=2),
    RO('zero_on_configure', False, 'zero both encoders at configure (pendulum hanging at rest!)'),
    RO('watchdog_period', 0.05, 'device watchdog: s without a valid command before the motor is zeroed',
       low=P.WATCHDOG_MIN_MS / 1000, high=P.WATCHDOG_MAX_MS / 1000),
    RO('command_timeout_samples', 3, 'samples without a fresh command before the driver sends u = 0',
       low=1),
    RO('claim_timeout_samples', 500, 'samples without any command of the controller that claimed the '
       'rig before another controller may claim it (rwpend_ros.claim)', low=1),
    RO('link_timeout', 0.1, 's without a valid frame before the link is declared lost',
       low=0.0, low_open=True),
    RO('handshake_timeout', 0.5, 's to wait for each handshake answer', low=0.0, low_open=True),
    RO('connect_timeout', 2.0, 's configure waits for the first handshake', low=0.0, low_open=True),
    RO('autostart', True, 'configure and activate at start'),
    RO('loop_dead_after', 2.0, 's of command timeout, after the loop had run, before the loop is '
       'reported dead (an ERROR on /diagnostics; exit status 3 if still dead at the end)',
       low=0.0, low_open=True),
    RO('duration', 0.0, 's of closed loop (from the first command sent to the device) after which the '
       'driver stops by itself, torque zero (0 = run until stopped; ./rwpend up --duration)', low=0.0),
    RO('start.encoders_subscribers', 1, 'subscribers of encoders (the estimator, a recorder) to wait '
       'for before the first sample is published: the device streams from the handshake, the run '
       'starts when everyone listens, so a bag misses nothing of it', low=0),
    RO('start.command_subscribers', 0, 'subscribers of command besides the driver to wait for before '
       'the first sample is published: the recorder of a stack whose controller runs in another '
       'process, and a separate estimator (./rwpend up --record sets it), so that the bag has the '
       'commands from the first sample', low=0),
    RO('frame_id', 'rwpend', 'frame_id of the published headers'),
    RO('diagnostics_period', 0.5, 's between /diagnostics messages', low=0.0, low_open=True),
    RO('health_log_period', 10.0, 's between two warnings of the same kind about the link (the first '
       'at once)', low=0.0, low_open=True),
]


def link_config(p: dict, rig) -> LinkConfig:
    """The link's settings from the driver's parameters ``p`` and the ``rig``'s sample period;
    settings the link refuses are a ConfigError with every reason."""
    cfg = LinkConfig(port=p['port'], baud=p['baud'], counts_per_rev=p['counts_per_rev'],
                     sample_period=float(rig.sample_period),
                     pendulum_sign=p['pendulum_sign'], motor_sign=p['motor_sign'],
                     zero_on_configure=bool(p['zero_on_configure']),
                     watchdog_period=float(p['watchdog_period']),
                     command_timeout_samples=p['command_timeout_samples'],
                     link_timeout=float(p['link_timeout']),
                     handshake_timeout=float(p['handshake_timeout']))
    errors = cfg.errors()
    if errors:
        raise ConfigError('driver parameters: ' + '; '.join(errors))
    return cfg


class DriverNode(LifecycleNode):
    """The rig's plant node: topics and parameters of the module doc; the link in DriverLink."""

    def __init__(self, loop_lock=None, external_command: bool = True) -> None:
        """``loop_lock``: the loop's lock when hosted in the loop's process (rwpend_loop.rig):
        every callback that touches the claim, the e-stop or the link's command runs holding it,
        as each sample does. ``external_command``: subscribe to ``command`` (False: the loop's
        own controller is the only one, as the simulator's in the loop's process)."""
        super().__init__('driver')
        self.loop_lock = loop_lock if loop_lock is not None else contextlib.nullcontext()
        #: hosted: called by the link thread for each sample to publish, (seq, pc, mc, sample,
        #: stamp_ns) -- the loop's sample (rwpend_loop.rig.RigHost); None: published here
        self.loop_hook = None
        #: hosted: subscribers of encoders in this process (the estimator, the recorder), which
        #: start.encoders_subscribers counts but DDS does not
        self.listeners_here = 0
        #: hosted: told of every e-stop change, before the next sample (the controller follows it)
        self.on_estop_change = None
        self.param_table = ParameterTable(self)
        p = self.param_table.declare(PARAMS)
        self.rig = declare_rig(self.param_table)
        if p['counts_per_rev'] == 0:
            p['counts_per_rev'] = int(self.rig.counts_per_rev)
        self.p = p
        self.cfg = link_config(p, self.rig)
        self.link: DriverLink | None = None
        self.thread: threading.Thread | None = None
        self.stop = threading.Event()
        #: wall time - monotonic time at start: the samples' stamps (on_sample)
        self.wall_offset_ns = time.time_ns() - time.monotonic_ns()
        self.active = False
        self.lifecycle = 'unconfigured'
        self.configure_failures = 0
        self.last_configure_error = ''
        self.estop = False
        self.estop_commands = 0          # commands refused because of the e-stop
        self.frame_id = p['frame_id']
        self._create_interfaces(p, external_command)
        # in the loop's slack: after a command is written, not while one waits (PERFORMANCE.md, "What each mechanism buys")
        self.diag_timer = SlackTimer(self, p['diagnostics_period'], self.publish_diagnostics)
        self.diag_lock = threading.Lock()   # the link thread reports losses at once, too
        self.health_before: dict = {}       # the link's counters at the previous diagnostics
        self.health_at = time.monotonic()
        self.health_log = link_health.Throttle(p['health_log_period'])
        self.trace = tracer('driver')       # None unless RWPEND_TRACE is set (profiling)
        self.link_thread_priority = ''
        self.loop_started: float | None = None   # monotonic time of the first command sent
        #: seq of the first sample published (None: still waiting for start.encoders_subscribers)
        self.first_published: int | None = None
        self.samples_before_start = 0            # samples read while waiting, not published
        self.waiting_since = time.monotonic()
        self.waiting_warned = False
        #: the loop's verdicts as the plant sees them (rwpend_ros.health): dead / alive
        self.loop = LoopHealth(self.rig.sample_period, dead_after_s=p['loop_dead_after'])
        self.finished = False
        if p['duration'] > 0:
            self.create_timer(0.1, self.check_duration)
        self.next_configure = 0.0
        self.autostart_timer = None
        if p['autostart']:
            # a fixed period (the EventsExecutor of rclpy 7.1.6 mishandles a re-armed timer)
            self.autostart_timer = self.create_timer(0.05, self.autostart)

    def _create_interfaces(self, p: dict, external_command: bool) -> None:
        """The publishers, the ``command`` subscription (``external_command``), the command
        claim, the e-stop's subscriptions, its latched state and its service."""
        # the link thread publishes wire bytes (rwpend_ros.wire): no message objects built
        self.pub_enc = self.create_publisher(EncoderCounts, 'encoders', QOS_CONTROL_PUB)
        self.pub_applied = self.create_publisher(AppliedCommand, 'applied', QOS_CONTROL_PUB)
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', QOS_STATUS)
        self.malformed_commands = 0
        # wire bytes, once each and in order (rwpend_ros.order)
        self.sub_cmd = (local_subscription(self, MotorCommand, 'command', self.on_command_raw, QOS_CONTROL,
                                           sender=wire.command_sender) if external_command else None)
        #: one controller at a time (rwpend_ros.claim), judged on the link's sample counter
        try:
            self.claim = CommandClaim(p['claim_timeout_samples'])
        except ValueError as exc:
            raise ConfigError(f'claim_timeout_samples {exc}') from exc
        estop_subscriptions(self, self.on_estop_topic)
        #: the plant's e-stop as it is (latched): the controller and the console follow it
        self.pub_estop_state = self.create_publisher(Bool, 'estop/state', QOS_LATCHED)
        self.pub_estop_state.publish(Bool(data=False))
        self.create_service(SetBool, '~/estop', self.on_estop_service)

    # ------------------------------------------------------------ autostart
    def autostart(self) -> None:
        """Configure (retried every second after connect_timeout while the device is absent),
        then activate."""
        if self.lifecycle == 'unconfigured' and time.monotonic() >= self.next_configure:
            self.trigger_configure()
            self.next_configure = time.monotonic() + 1.0
        if self.lifecycle == 'inactive':
            self.trigger_activate()
        if self.lifecycle == 'active':
            self.autostart_timer.cancel()

    # ------------------------------------------------------------ lifecycle
    def _log(self, level: str, msg: str) -> None:
        # one call site per severity: rclpy's logger refuses a severity change at a call site
        lg = self.get_logger()
        if level == 'error':
            lg.error(msg)
        elif level == 'warn':
            lg.warning(msg)
        else:
            lg.info(msg)

    # transitions and command callbacks all run on the executor's thread (one at a time); the
    # link thread only publishes samples and reads self.active
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.link = DriverLink(self.cfg, on_sample=self.on_sample, log=self._log, trace=self.trace)
        self.health_before = {}             # a new link counts from zero
        deadline = time.monotonic() + self.p['connect_timeout']
        ok = False
        while time.monotonic() < deadline:
            if self.link.try_connect():
                ok = True
                break
            if self.link.fatal:
                break
            time.sleep(min(self.link.next_attempt - self.link.clock(), max(0.0, deadline - time.monotonic()), 0.5))
        if not ok:
            self.configure_failures += 1
            self.last_configure_error = self.link.error
            self._say_configure_failed()
            self.link.close()
            self.link = None
            return TransitionCallbackReturn.FAILURE
        self.last_configure_error = ''
        self.stop.clear()
        self.thread = threading.Thread(target=self.link_loop, name='driver-link', daemon=True)
        self.thread.start()
        self.lifecycle = 'inactive'
        return TransitionCallbackReturn.SUCCESS

    def _say_configure_failed(self) -> None:
        """The first failure to open the link, with the reason and, for a device path that does
        not exist, the serial ports there are; then, while autostart retries, one line every
        :data:`RETRY_NOTE_S` s, so that a stack waiting for its rig is never silent."""
        now = time.monotonic()
        retrying = self.p['autostart'] and not self.link.fatal
        if self.configure_failures == 1 or self.link.fatal:
            self.first_failure_at = self.retry_note_at = now
            hint = absent_port_hint(self.p['port'], serial_ports_present())
            again = (f'; retrying every {self.p["connect_timeout"] + 1.0:g} s until the rig answers '
                     '(Ctrl-C to stop)') if retrying else ''
            self.get_logger().error(f'configure failed: {self.link.error}' + (f' ({hint})' if hint else '') + again)
        elif retrying and now - self.retry_note_at >= RETRY_NOTE_S:
            self.retry_note_at = now
            self.get_logger().warning(f'no rig at {self.p["port"]} yet: {self.configure_failures} attempts in '
                                      f'{now - self.first_failure_at:.0f} s, the last: {self.link.error}')

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.link.set_active(not self.estop)    # a latched e-stop keeps the amplifier off
        if self.first_published is None:
            self.waiting_since = time.monotonic()   # the wait for subscribers starts now
        self.active = True
        self.lifecycle = 'active'
        self.get_logger().info('active: amplifier enabled, zero torque until commands arrive')
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = False
        self.link.set_active(False)
        self.lifecycle = 'inactive'
        self.get_logger().info('inactive: torque zero, amplifier disabled')
        return TransitionCallbackReturn.SUCCESS

    def _teardown(self) -> None:
        self.active = False
        self.stop.set()
        if self.thread is not None:
            self.thread.join(timeout=2.0)
            self.thread = None
        if self.link is not None:
            self.link.close()
            if self.link.counters.connects:
                self._log('info', f'serial link: {self.link.summary()}')
        self.lifecycle = 'unconfigured'

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown()
        self.link = None
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown()
        self.lifecycle = 'finalized'
        return TransitionCallbackReturn.SUCCESS

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown()
        return TransitionCallbackReturn.SUCCESS

    # ------------------------------------------------------------ data path
    def link_loop(self) -> None:
        # one real-time priority above the process (and the other loop processes): each sample
        # is taken as it comes, ahead of the command callback and the DDS threads
        self.link_thread_priority = raise_thread_priority(1)
        link = self.link
        was = True
        while not self.stop.is_set():
            try:
                link.poll()
            except Exception as exc:  # noqa: BLE001 - the link thread must never die
                link.lose(f'unexpected {type(exc).__name__}: {exc}')
            if link.connected != was:
                was = link.connected
                self.publish_diagnostics()      # report losses and recoveries at once

    def on_sample(self, seq: int, pc: int, mc: int, s, rx: float) -> None:
        """In the link thread, as each sample is read: encoders as wire bytes, stamped now -- on the
        wall clock as it read at start, advanced by the monotonic clock, so the stamps never go
        back when the wall clock is stepped (NTP): the subscribers' order gates (rwpend_ros.order)
        would take a stamp that goes back for a stale sample."""
        link = self.link
        if not self.active or link is None:
            return
        if self.first_published is None and not self._listeners_ready(seq):
            self.samples_before_start += 1
            return
        stamp_ns = time.monotonic_ns() + self.wall_offset_ns
        if self.loop_hook is not None:
            self.loop_hook(seq, pc, mc, s, stamp_ns)    # the loop's sample, then publish_sample
            return
        self.publish_sample(seq, pc, mc, s, stamp_ns)

    def publish_sample(self, seq: int, pc: int, mc: int, s, stamp_ns: int) -> bytes:
        """``encoders`` and ``applied`` of a sample (its header stamped ``stamp_ns``), and the
        loop's health as the plant sees it; returns the header's bytes."""
        header = wire.pack_header(*divmod(stamp_ns, 1_000_000_000), self.frame_id)
        if self.trace is not None:
            self.trace('drv.pub', seq)
        link = self.link
        try:
            self.pub_enc.publish(wire.pack_encoders(header, seq, pc, mc))
            # after the encoders (the loop waits for those): what the motor was driven with
            self.pub_applied.publish(wire.pack_applied(header, seq, *link.applied(seq, s)))
        except Exception:  # noqa: BLE001 - context shut down under the link thread
            self.stop.set()
        self._loop_event(self.loop.sample(False, link.timed_out))
        return header

    def _listeners_ready(self, seq: int) -> bool:
        """Before the first published sample: True once ``start.encoders_subscribers`` listen to
        encoders (said in the log); a wait of more than 5 s is said once, with who is missing."""
        need = max(0, self.p['start.encoders_subscribers'] - self.listeners_here)
        have = self.pub_enc.get_subscription_count()
        need_cmd = self.p['start.command_subscribers']
        # (a graph query: only when asked for, this runs on every sample read while waiting)
        have_cmd = (self.count_subscribers(self.resolve_topic_name('command')) - (self.sub_cmd is not None)
                    if need_cmd else 0)
        if have >= need and have_cmd >= need_cmd:
            self.first_published = seq
            self.get_logger().info(f'{have} subscriber(s) of encoders: publishing from sample {seq} '
                                   f'({self.samples_before_start} read before, not published)')
            return True
        if not self.waiting_warned and time.monotonic() - self.waiting_since > 5.0:
            self.waiting_warned = True
            self.get_logger().warning(f'waiting for {need} subscriber(s) of encoders (the estimator, a '
                                      f'recorder), {have} so far, and {need_cmd} of command besides the '
                                      f'driver (a recorder), {have_cmd} so far: no sample is published '
                                      'until then')
        return False

    def on_command_raw(self, data: bytes) -> None:
        """A command as wire bytes (rwpend_ros.wire); malformed bytes are counted, nothing else
        changes."""
        try:
            seq, u, source, release = wire.unpack_command_sender(data)
        except (struct.error, IndexError):
            self.malformed_commands += 1
            return
        if self.trace is not None:
            self.trace('drv.cmd', seq)
        with self.loop_lock:
            self._offer(source, seq, u, release)
        self.diag_timer.sample_done()

    def _offer(self, source: int, seq: int, u: float, release: bool) -> bool:
        """The command (seq, u) of controller ``source`` to the link, if that controller may
        drive the rig (rwpend_ros.claim, judged on the link's newest sample); True when sent. A
        release sends u = 0 at once. A change of the claim is said at once (log, /diagnostics)."""
        link = self.link
        newest = link.last_seq if link is not None and link.last_seq is not None else 0
        taken = self.claim.admit(source, newest, lambda: self.command(seq, u), release)
        event = self.claim.event
        if event == 'refused':
            self.get_logger().warning(f'command from controller {format_id(source)} refused: the rig is '
                                      f'claimed by {format_id(self.claim.holder)}')
        elif event is not None:
            self.get_logger().info(f'rig {event} by controller {format_id(source)}')
        if event == 'released' and link is not None and link.last_seq is not None:
            self.command(link.last_seq, 0.0)
        if event is not None:
            self.publish_diagnostics()
        return taken

    def command(self, seq: int, u: float) -> bool:
        """Offer a command to the link; True when it was sent to the device."""
        link = self.link
        if self.estop:
            self.estop_commands += 1
            return False
        if link is None or not self.active:
            return False
        if not link.command(seq, u)[0]:
            return False
        if self.loop_started is None:
            self.loop_started = time.monotonic()
        self._loop_event(self.loop.command())
        return True

    def _loop_event(self, event: str | None) -> None:
        """The loop's health changed: said at once, in the log and on /diagnostics."""
        if event == 'dead':
            self.get_logger().error(self.loop.dead_reason())
        elif event == 'alive':
            self.get_logger().info('the loop is answering again: commands are fresh')
        else:
            return
        self.publish_diagnostics()

    def exit_status(self) -> int:
        """:data:`rwpend_ros.health.EXIT_LOOP_DEAD` when the loop was dead at the end; 1 when
        the rig never sent a sample in the whole run (the link never opened: a wrong port, the
        rig unplugged) -- a run that never reached the rig is not a success."""
        if self.never_reached_the_rig():
            why = f': {self.last_configure_error}' if self.last_configure_error else ''
            print(f'driver: the rig sent no sample in this run ({self.configure_failures} failed '
                  f'attempt(s) to open the link{why})', file=sys.stderr, flush=True)
            return 1
        if self.loop.dead:
            print(f'driver: {self.loop.dead_reason()} (at the end of the run)', file=sys.stderr, flush=True)
            return EXIT_LOOP_DEAD
        return 0

    def never_reached_the_rig(self) -> bool:
        """No sample read from the rig in the whole run, the link having failed to open."""
        return (self.configure_failures > 0 and self.first_published is None
                and self.samples_before_start == 0 and self.loop_started is None)

    def check_duration(self) -> None:
        """``duration`` s after the first command: finished, the runner ends the process
        (rwpend_ros.runner; close() zeroes the motor)."""
        if (not self.finished and self.loop_started is not None
                and time.monotonic() - self.loop_started >= self.p['duration']):
            self.get_logger().info(f"duration reached: {self.p['duration']:g} s since the first command")
            self.finished = True

    # ------------------------------------------------------------ e-stop
    def set_estop(self, on: bool) -> str:
        with self.loop_lock:
            return self._set_estop(on)

    def _set_estop(self, on: bool) -> str:
        changed = self.estop != on
        self.estop = on
        link = self.link
        if link is not None and self.active:
            link.set_active(not on)     # off: zero command + ENABLE 0; on: ENABLE 1, zero until a command
        if changed:
            if self.on_estop_change is not None:
                self.on_estop_change(bool(on))
            self.pub_estop_state.publish(Bool(data=bool(on)))
            # one call site per severity: rclpy refuses a severity change at a call site
            if on:
                self.get_logger().warning('E-STOP raised: motor at zero, amplifier disabled')
            else:
                self.get_logger().info('e-stop cleared')
            self.publish_diagnostics()
        return ('e-stop raised: motor at zero, amplifier disabled until cleared' if on
                else 'e-stop cleared')

    def on_estop_topic(self, msg: Bool) -> None:
        self.set_estop(bool(msg.data))

    def on_estop_service(self, req: SetBool.Request, resp: SetBool.Response) -> SetBool.Response:
        resp.message = self.set_estop(bool(req.data))
        resp.success = True
        return resp

    # ------------------------------------------------------------ diagnostics
    def publish_diagnostics(self) -> None:
        """The link's state and counters, with the worst of its state and its health over the
        window since the previous report (:func:`rwpend_driver.link_health.assess`); each finding is
        also logged, with what to do, once per kind every health_log_period s."""
        with self.diag_lock:
            link = self.link
            values = {'lifecycle': self.lifecycle, 'port': self.cfg.port, 'estop': self.estop,
                      'estop_commands': self.estop_commands, 'malformed_commands': self.malformed_commands,
                      'command_order': self.sub_cmd.summary() if self.sub_cmd is not None else 'loop',
                      'first_published_seq': -1 if self.first_published is None else self.first_published,
                      'samples_before_start': self.samples_before_start,
                      'link_thread_priority': self.link_thread_priority, **self.loop.values(),
                      **self.claim.values()}
            if link is None:
                level = link_health.ERROR if self.last_configure_error or self.estop else link_health.WARN
                msg = (f'not configured: {self.last_configure_error}' if self.last_configure_error
                       else 'not configured')
                values['configure_failures'] = self.configure_failures
            else:
                snap = link.snapshot()
                values.update(snap)
                level, msg = self._link_state(snap)
                findings = self._link_health(link, values)
                if findings:
                    level = max(level, link_health.level_of(findings))
                    msg += '; ' + '; '.join(f.what for f in findings)
            if self.loop.dead:
                level, msg = link_health.ERROR, self.loop.dead_reason() + '; ' + msg
            if self.estop:
                level, msg = link_health.ERROR, 'e-stop latched: motor at zero, amplifier disabled; ' + msg
        try:
            publish_diagnostic(self.pub_diag, self.get_clock().now().nanoseconds,
                               f'{self.get_namespace().rstrip("/")}/driver: serial link', self.cfg.port,
                               level, msg, values)
        except Exception:  # noqa: BLE001 - context shutting down
            pass

    def _link_state(self, snap: dict) -> tuple[int, str]:
        if not snap['connected']:
            return link_health.ERROR, f'link down ({snap["error"]}); reconnecting, no encoders'
        if snap.get('device.watchdog_tripped'):
            return link_health.WARN, 'device watchdog tripped: motor at zero'
        if snap['command_timed_out'] and self.active and snap['timeouts']:
            return link_health.WARN, 'command timeout: sending u = 0'
        if self.claim.intruding(self.link.last_seq or 0, int(round(1.0 / self.rig.sample_period))):
            return link_health.WARN, (f'commands of controller {format_id(self.claim.intruder)} refused: '
                                      f'the rig is claimed by {format_id(self.claim.holder)}')
        return link_health.OK, 'active' if self.active else 'connected, inactive (torque off)'

    def _link_health(self, link: DriverLink, values: dict) -> list:
        """Findings over the window since the last report; logs those due."""
        now = time.monotonic()
        after = link.counter_values()
        max_delay = link.take_window_max_delay_ms()
        values['window_max_delay_ms'] = f'{max_delay:.3f}'
        findings = link_health.assess(self.health_before, after, now - self.health_at, max_delay) \
            if self.health_before else []
        self.health_before, self.health_at = after, now
        for f in self.health_log.due(findings, now):
            self._log('error' if f.level == link_health.ERROR else 'warn', f'serial link: {f.what}. {f.advice}')
        return findings

    def close(self) -> None:
        """Called by run_node before destruction: torque zero, amplifier off, port closed."""
        self._teardown()
        self.publish_diagnostics()


def main(args=None) -> int:
    return run_node(DriverNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
