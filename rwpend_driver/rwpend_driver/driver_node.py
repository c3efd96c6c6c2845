"""``driver`` node: the real rig (or the emulator) over a serial port, with the simulator's topics.

Publishes ``encoders`` (EncoderCounts: seq = monotone sample counter, header.stamp = receive
time), subscribes ``command`` (MotorCommand), publishes ``/diagnostics``.  Managed lifecycle
(rclpy.lifecycle): configure = open the port and handshake; activate = enable the amplifier and
publish; deactivate = zero torque, amplifier off; cleanup = close.  ``autostart`` (default
true) configures and activates at start (retrying configure while the device is absent).

Latched e-stop, as on the simulator: topic ``estop`` (std_msgs/Bool, transient local) and
service ``~/estop`` (std_srvs/SetBool; ``./rwpend estop [--clear]``).  Raised, it zeros the
motor and disables the amplifier at once (a zero command, then ENABLE 0), refuses every
command, and holds so -- across reconnections and lifecycle transitions -- until it is
explicitly cleared; cleared, the amplifier is enabled again and the torque stays zero until a
fresh command arrives.  Encoders keep streaming throughout.

All protocol and link logic lives in :mod:`rwpend_driver.link` / :mod:`rwpend_driver.protocol`.
"""
from __future__ import annotations

import os
import struct
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from std_msgs.msg import Bool
from std_srvs.srv import SetBool

from rwpend_msgs.msg import EncoderCounts, MotorCommand
from rwpend_ros import wire
from rwpend_ros.common import (QOS_CONTROL, QOS_CONTROL_PUB, QOS_LATCHED, QOS_STATUS, ConfigError, LocalPublisher,
                               LockedCallbacks, SlackTimer, declare_read_only, declare_rig, fast_path_values,
                               local_subscription, locked, publish_diagnostic, run_node)

from .link import DriverLink, LinkConfig

PARAMS = {
    'port': ('', 'serial device of the rig (e.g. /dev/ttyACM0, or the emulator\'s --link path)'),
    'baud': (921600, 'baud rate (ignored by USB CDC and ptys)'),
    'counts_per_rev': (0, 'encoder counts per revolution, checked against what the device reports '
                       '(0 = rig.counts_per_rev of the rig YAML, the single source of truth)'),
    'pendulum_sign': (1, 'direction sign of the pendulum encoder (+1 or -1)'),
    'motor_sign': (1, 'direction sign of the motor: its encoder and its command (+1 or -1)'),
    'zero_on_configure': (False, 'zero both encoders at configure (pendulum hanging at rest!)'),
    'watchdog_period': (0.05, 'device watchdog: s without a valid command before the motor is zeroed'),
    'command_timeout_samples': (3, 'samples without a fresh command before the driver sends u = 0'),
    'link_timeout': (0.1, 's without a valid frame before the link is declared lost'),
    'handshake_timeout': (0.5, 's to wait for each handshake answer'),
    'connect_timeout': (2.0, 's configure waits for the first handshake'),
    'autostart': (True, 'configure and activate at start'),
    'frame_id': ('rwpend', 'frame_id of the published headers'),
    'diagnostics_period': (0.5, 's between /diagnostics messages'),
}


class DriverNode(LockedCallbacks, LifecycleNode):
    def __init__(self) -> None:
        super().__init__('driver')
        p = declare_read_only(self, PARAMS)
        self.rig = declare_rig(self)
        if p['counts_per_rev'] == 0:
            p['counts_per_rev'] = int(self.rig.counts_per_rev)
        self.p = p
        self.cfg = LinkConfig(port=p['port'], baud=p['baud'], counts_per_rev=p['counts_per_rev'],
                              pendulum_sign=p['pendulum_sign'], motor_sign=p['motor_sign'],
                              zero_on_configure=bool(p['zero_on_configure']),
                              watchdog_period=float(p['watchdog_period']),
                              command_timeout_samples=p['command_timeout_samples'],
                              link_timeout=float(p['link_timeout']),
                              handshake_timeout=float(p['handshake_timeout']))
        errors = self.cfg.errors()
        for name in ('connect_timeout', 'diagnostics_period'):
            if not isinstance(p[name], (int, float)) or not p[name] > 0:
                errors.append(f'{name} must be > 0, got {p[name]!r}')
        if errors:
            raise ConfigError('driver parameters: ' + '; '.join(errors))
        self.link: DriverLink | None = None
        self.thread: threading.Thread | None = None
        self.stop = threading.Event()
        self.active = False
        self.lifecycle = 'unconfigured'
        self.configure_failures = 0
        self.last_configure_error = ''
        self.estop = False
        self.estop_commands = 0          # commands refused because of the e-stop
        self.enc = EncoderCounts()
        self.enc.header.frame_id = p['frame_id']
        # first to an estimator in another process of this host, then DDS (rwpend_ros.hostbus)
        self.pub_enc = LocalPublisher(self, EncoderCounts, 'encoders', QOS_CONTROL_PUB)
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', QOS_STATUS)
        self.malformed_commands = 0
        # also straight from a controller in another process of this host (wire bytes)
        local_subscription(self, MotorCommand, 'command', self.on_command_raw, QOS_CONTROL)
        self.create_subscription(Bool, 'estop', self.on_estop_topic, QOS_LATCHED)
        self.create_service(SetBool, '~/estop', self.on_estop_service)
        # in the loop's slack: after a command is written, not while one waits (PERFORMANCE.md 19.)
        self.diag_timer = SlackTimer(self, p['diagnostics_period'], self.publish_diagnostics)
        self.autostart_timer = None
        if p['autostart']:
            self.autostart_timer = self.create_timer(0.01, self.autostart)

    # ------------------------------------------------------------ autostart
    def autostart(self) -> None:
        """Configure (retried every connect_timeout while the device is absent), then activate."""
        if self.lifecycle == 'unconfigured':
            self.autostart_timer.timer_period_ns = int(1e9)
            self.trigger_configure()
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

    # transitions run holding the callback lock, like every other callback of the node (a
    # command taken by the fast path's thread never sees a transition half done)
    @locked
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.link = DriverLink(self.cfg, on_sample=self.on_sample, log=self._log)
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
            if self.configure_failures == 1 or self.link.fatal:
                self.get_logger().error(f'configure failed: {self.link.error}')
            self.link.close()
            self.link = None
            return TransitionCallbackReturn.FAILURE
        self.last_configure_error = ''
        self.stop.clear()
        self.thread = threading.Thread(target=self.link_loop, name='driver-link', daemon=True)
        self.thread.start()
        self.lifecycle = 'inactive'
        return TransitionCallbackReturn.SUCCESS

    @locked
    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.link.set_active(not self.estop)    # a latched e-stop keeps the amplifier off
        self.active = True
        self.lifecycle = 'active'
        self.get_logger().info('active: amplifier enabled, zero torque until commands arrive')
        return TransitionCallbackReturn.SUCCESS

    @locked
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
        self.lifecycle = 'unconfigured'

    @locked
    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown()
        self.link = None
        return TransitionCallbackReturn.SUCCESS

    @locked
    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown()
        self.lifecycle = 'finalized'
        return TransitionCallbackReturn.SUCCESS

    @locked
    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown()
        return TransitionCallbackReturn.SUCCESS

    # ------------------------------------------------------------ data path
    def link_loop(self) -> None:
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

    def on_sample(self, seq: int, pc: int, mc: int, s) -> None:
        if not self.active:
            return
        now = time.time_ns()
        e = self.enc
        e.header.stamp.sec, e.header.stamp.nanosec = divmod(now, 1_000_000_000)
        e.seq, e.pendulum_counts, e.motor_counts = seq, pc, mc
        try:
            self.pub_enc.publish(e)
        except Exception:  # noqa: BLE001 - context shut down under the link thread
            self.stop.set()

    def on_command_raw(self, data: bytes) -> None:
        """A command as wire bytes (rwpend_ros.wire); malformed bytes are counted, nothing else
        changes."""
        try:
            seq, u = wire.unpack_command(data)
        except (struct.error, IndexError):
            self.malformed_commands += 1
            return
        self.command(seq, u)
        self.diag_timer.sample_done()

    def command(self, seq: int, u: float) -> None:
        link = self.link
        if self.estop:
            self.estop_commands += 1
            return
        if link is None or not self.active:
            return
        link.command(seq, u)

    # ------------------------------------------------------------ e-stop
    def set_estop(self, on: bool) -> str:
        changed = self.estop != on
        self.estop = on
        link = self.link
        if link is not None and self.active:
            link.set_active(not on)     # off: zero command + ENABLE 0; on: ENABLE 1, zero until a command
        if changed:
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
        link = self.link
        values = {'lifecycle': self.lifecycle, 'port': self.cfg.port, 'estop': self.estop,
                  'estop_commands': self.estop_commands, 'malformed_commands': self.malformed_commands,
                  **fast_path_values(self)}
        if self.estop:
            level, msg = DiagnosticStatus.ERROR, 'e-stop latched: motor at zero, amplifier disabled'
            if link is not None:
                values.update(link.snapshot())
        elif link is None:
            level = DiagnosticStatus.ERROR if self.last_configure_error else DiagnosticStatus.WARN
            msg = (f'not configured: {self.last_configure_error}' if self.last_configure_error
                   else 'not configured')
            values['configure_failures'] = self.configure_failures
        else:
            snap = link.snapshot()
            values.update(snap)
            if not snap['connected']:
                level, msg = DiagnosticStatus.ERROR, f'link down ({snap["error"]}); reconnecting, no encoders'
            elif snap.get('device.watchdog_tripped'):
                level, msg = DiagnosticStatus.WARN, 'device watchdog tripped: motor at zero'
            elif snap['command_timed_out'] and self.active and snap['timeouts']:
                level, msg = DiagnosticStatus.WARN, 'command timeout: sending u = 0'
            elif self.active:
                level, msg = DiagnosticStatus.OK, 'active'
            else:
                level, msg = DiagnosticStatus.OK, 'connected, inactive (torque off)'
        try:
            publish_diagnostic(self.pub_diag, self.get_clock().now().nanoseconds,
                               f'{self.get_namespace().rstrip("/")}/driver: serial link', self.cfg.port,
                               level, msg, values)
        except Exception:  # noqa: BLE001 - context shutting down
            pass

    def close(self) -> None:
        """Called by run_node before destruction: torque zero, amplifier off, port closed."""
        self._teardown()
        self.publish_diagnostics()


def main(args=None) -> int:
    # The data path runs in the driver's own link thread; the executor only serves commands,
    # lifecycle services and a re-armed autostart timer, which the EventsExecutor of rclpy 7.1.6
    # does not handle reliably (see rwpend_ros.common.make_executor).
    os.environ.setdefault('RWPEND_EXECUTOR', 'single')
    return run_node(DriverNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
