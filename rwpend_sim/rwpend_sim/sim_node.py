"""``sim`` node: the simulated Reaction Wheel Pendulum, with the rig's interface.

Publishes ``encoders`` (EncoderCounts) every h, applies the latest ``command`` (MotorCommand)
with zero-order hold, publishes ``sim/true_state`` (PlantState), serves ``sim/disturb``
(Disturb), enforces the command timeout and the latched e-stop (``estop`` topic,
std_msgs/Bool, and ``~/estop`` service, std_srvs/SetBool), reports on ``/diagnostics``.

Two time modes (parameter ``lockstep``):
* real time: samples on the wall clock, like the rig (a thread with absolute deadlines);
* lockstep: publishes ``/clock``; for sample k it waits for the command answering seq k
  (``lockstep_timeout`` s of wall time, then u = 0 for that sample, counted) before
  integrating; runs as fast as the loop allows; identical inputs give identical outputs.

All algorithms live in :mod:`rwpend_sim.sim_core` and :mod:`rwpend_model.plant`.
"""
from __future__ import annotations

import threading
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Bool
from std_srvs.srv import SetBool

from rwpend_msgs.msg import EncoderCounts, MotorCommand, PlantState
from rwpend_msgs.srv import Disturb
from rwpend_ros.common import (QOS_CONTROL, QOS_CONTROL_PUB, QOS_LATCHED, QOS_STATUS, ConfigError, declare_rig,
                               diagnostic_status, run_node)
from rwpend_sim.sim_core import SimCore

PARAMS = {
    'lockstep': (False, 'lockstep time mode: publish /clock, wait for the command of each sample'),
    'lockstep_timeout': (0.5, 'lockstep: wall seconds to wait for the command of a sample'),
    'start.delay': (0.5, 'wall seconds to wait after the loop is connected, before sample 0'),
    'start.encoders_subscribers': (1, 'subscribers of encoders to wait for before sample 0 (2 with a recorder)'),
    'start.true_state_subscribers': (0, 'subscribers of sim/true_state to wait for before sample 0'),
    'start.state_subscribers': (0, 'lockstep: subscribers of state (the controller) to wait for before sample 0'),
    'start.first_command_timeout': (10.0, 'lockstep: wall seconds sample 0 waits for its command '
                                    '(start-up under load; later samples wait lockstep_timeout)'),
    'command_timeout_samples': (3, 'samples without a fresh command before u = 0'),
    'initial.theta': (0.0, 'initial pendulum angle (rad, 0 hanging, pi upright)'),
    'initial.theta_dot': (0.0, 'initial pendulum angular velocity (rad/s)'),
    'initial.wheel_angle': (0.0, 'initial absolute wheel angle (rad)'),
    'initial.wheel_rate': (0.0, 'initial absolute wheel angular velocity (rad/s)'),
    'friction': (True, 'rotor friction (3.17) with stiction and pendulum-axis friction'),
    'motor_lag': (True, 'first-order current lag T_e'),
    'pwm': (True, 'PWM duty quantization of the command'),
    'back_emf': (True, 'back-EMF cut-off (2.13)'),
    'publish_true_state': (True, 'publish sim/true_state every sample'),
    'taps.times': ([-1.0], 'scripted taps: simulated times (s); [-1.0] = none'),
    'taps.sizes': ([0.0], 'scripted taps: theta_dot jumps (rad/s), one per time'),
    'duration': (0.0, 'stop after this many simulated seconds (0 = run until stopped)'),
    'frame_id': ('rwpend', 'frame_id of the published headers'),
    'diagnostics_period': (1.0, 'seconds between /diagnostics messages'),
}


class SimNode(Node):
    def __init__(self) -> None:
        super().__init__('sim')
        self.rig = declare_rig(self)
        for name, (default, descr) in PARAMS.items():
            self.declare_parameter(name, default, ParameterDescriptor(description=descr, read_only=True))
        p = {name: self.get_parameter(name).value for name in PARAMS}
        if (p['lockstep_timeout'] <= 0 or p['diagnostics_period'] <= 0 or p['duration'] < 0
                or p['start.first_command_timeout'] <= 0):
            raise ConfigError('lockstep_timeout, start.first_command_timeout and diagnostics_period '
                              'must be > 0, duration >= 0')
        try:
            self.core = SimCore(self.rig, command_timeout_samples=p['command_timeout_samples'],
                                theta=p['initial.theta'], theta_dot=p['initial.theta_dot'],
                                wheel_angle=p['initial.wheel_angle'], wheel_rate=p['initial.wheel_rate'],
                                friction=p['friction'], motor_lag=p['motor_lag'], pwm=p['pwm'],
                                back_emf=p['back_emf'])
            times, sizes = list(p['taps.times']), list(p['taps.sizes'])
            if times == [-1.0]:
                times, sizes = [], []
            self.core.schedule_taps(times, sizes)
        except (ValueError, TypeError) as exc:
            raise ConfigError(str(exc)) from exc
        self.p = p
        self.h = self.rig.sample_period
        self.lockstep = bool(p['lockstep'])
        self.lock = threading.Condition()
        self.stop = threading.Event()
        self.finished = False

        self.pub_enc = self.create_publisher(EncoderCounts, 'encoders', QOS_CONTROL_PUB)
        self.pub_true = self.create_publisher(PlantState, 'sim/true_state', QOS_CONTROL_PUB)
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', QOS_STATUS)
        self.pub_clock = self.create_publisher(Clock, '/clock', QOS_CONTROL_PUB) if self.lockstep else None
        self.create_subscription(MotorCommand, 'command', self.on_command, QOS_CONTROL)
        self.create_subscription(Bool, 'estop', self.on_estop_topic, QOS_LATCHED)
        self.create_service(Disturb, 'sim/disturb', self.on_disturb)
        self.create_service(SetBool, '~/estop', self.on_estop_service)
        self.create_timer(p['diagnostics_period'], self.publish_diagnostics)

        self.enc = EncoderCounts()
        self.enc.header.frame_id = p['frame_id']
        self.true = PlantState()
        self.true.header.frame_id = p['frame_id']
        self.clock_msg = Clock()
        self.wall_start = time.monotonic()
        self.overruns = 0
        self.thread = threading.Thread(target=self._run_loop, name='sim-loop', daemon=True)
        self.thread.start()
        mode = 'lockstep' if self.lockstep else 'real time'
        self.get_logger().info(f'simulated rig: h = {self.h * 1e3:g} ms, {mode}, '
                               f'a = {self.rig.a:.3f}, b_p = {self.rig.b_p:.4f}, b_r = {self.rig.b_r:.2f}')

    # ------------------------------------------------------------ callbacks
    def on_command(self, msg: MotorCommand) -> None:
        with self.lock:
            ok, _ = self.core.command(msg.seq, msg.u)
            if ok:
                self.lock.notify_all()

    def set_estop(self, on: bool) -> str:
        with self.lock:
            changed = self.core.estop != on
            self.core.estop = on
        if changed:
            # one call site per severity: rclpy refuses a severity change at a call site
            if on:
                self.get_logger().warn('E-STOP raised: motor held at zero')
            else:
                self.get_logger().info('e-stop cleared')
            self.publish_diagnostics()
        return 'e-stop raised: motor at zero until cleared' if on else 'e-stop cleared'

    def on_estop_topic(self, msg: Bool) -> None:
        self.set_estop(bool(msg.data))

    def on_estop_service(self, req: SetBool.Request, resp: SetBool.Response) -> SetBool.Response:
        resp.message = self.set_estop(bool(req.data))
        resp.success = True
        return resp

    def on_disturb(self, req: Disturb.Request, resp: Disturb.Response) -> Disturb.Response:
        with self.lock:
            if req.kind == Disturb.Request.TAP:
                ok, msg = self.core.tap(req.magnitude)
            elif req.kind == Disturb.Request.TORQUE:
                ok, msg = self.core.torque(req.magnitude, req.duration)
            else:
                ok, msg = False, f'unknown disturbance kind {req.kind} (TAP=0, TORQUE=1)'
        resp.success, resp.message = ok, msg
        if ok:
            self.get_logger().info(f'disturb: {msg}')
        else:
            self.get_logger().warn(f'disturb refused: {msg}')
        return resp

    # ------------------------------------------------------------ publishing
    def publish_sample(self, stamp_ns: int) -> None:
        seq, pc, mc = self.core.sample()
        sec, nsec = divmod(stamp_ns, 1_000_000_000)
        enc = self.enc
        enc.header.stamp.sec, enc.header.stamp.nanosec = sec, nsec
        enc.seq, enc.pendulum_counts, enc.motor_counts = seq, pc, mc
        self.pub_enc.publish(enc)
        if self.p['publish_true_state']:
            s = self.core.plant.state
            t = self.true
            t.header.stamp.sec, t.header.stamp.nanosec = sec, nsec
            t.seq = seq
            t.theta, t.theta_dot, t.wheel_angle, t.wheel_rate = s.theta, s.theta_dot, s.wheel_angle, s.wheel_rate
            t.u_commanded = self.core.plant.u_held
            t.u_applied, t.friction, t.stuck = s.torque, s.friction, s.stuck
            t.disturbance = self.core.plant.disturbance
            t.command_timeout = self.core.timed_out
            self.pub_true.publish(t)

    def done(self) -> bool:
        d = self.p['duration']
        return d > 0 and self.core.plant.t >= d - 1e-9

    def wait_for_loop(self, need_command: bool) -> None:
        """Hold sample 0 until the estimator (and a recorder, if asked) are subscribed, so
        nothing of the run is missed; then let discovery settle."""
        n_enc = self.p['start.encoders_subscribers']
        n_true = self.p['start.true_state_subscribers']
        while not self.stop.is_set():
            if (self.pub_enc.get_subscription_count() >= n_enc
                    and self.pub_true.get_subscription_count() >= n_true
                    and (not need_command or (
                        self.count_publishers(self.resolve_topic_name('command')) > 0
                        and self.count_subscribers(self.resolve_topic_name('state'))
                        >= self.p['start.state_subscribers']))):
                break
            time.sleep(0.02)
        time.sleep(self.p['start.delay'])
        self.wall_start = time.monotonic()

    def _run_loop(self) -> None:
        """The loop thread.  SIGINT shuts the context down under it (rclpy's handler runs before
        close()): a publish failing then is the normal end, not an error."""
        try:
            (self.loop_lockstep if self.lockstep else self.loop_realtime)()
        except Exception:  # noqa: BLE001 - re-raised unless the context is gone
            if self.context.ok() and not self.stop.is_set():
                raise

    def loop_realtime(self) -> None:
        self.wait_for_loop(need_command=False)
        period_ns = int(round(self.h * 1e9))
        t0_ros = self.get_clock().now().nanoseconds
        t0 = time.monotonic_ns()
        k = 0
        while not self.stop.is_set() and not self.done():
            with self.lock:
                self.publish_sample(t0_ros + k * period_ns)
            k += 1
            deadline = t0 + k * period_ns
            delay = deadline - time.monotonic_ns()
            if delay > 0:
                time.sleep(delay / 1e9)
            elif delay < -period_ns:
                self.overruns += 1
            with self.lock:
                self._advance()
        self.finish()

    def loop_lockstep(self) -> None:
        self.wait_for_loop(need_command=True)
        period_ns = int(round(self.h * 1e9))
        timeout = self.p['lockstep_timeout']
        while not self.stop.is_set() and not self.done():
            k = self.core.k
            stamp = k * period_ns
            sec, nsec = divmod(stamp, 1_000_000_000)
            self.clock_msg.clock.sec, self.clock_msg.clock.nanosec = sec, nsec
            self.pub_clock.publish(self.clock_msg)
            with self.lock:
                self.publish_sample(stamp)
                answered = self.lock.wait_for(lambda: self.core.u_seq >= k or self.stop.is_set(),
                                              timeout if k else self.p['start.first_command_timeout'])
                if not answered and k == 0:
                    self.get_logger().warn('lockstep: no command for sample 0 within '
                                           f"{self.p['start.first_command_timeout']:g} s; running with u = 0")
                if not answered:
                    self.core.counters.late_commands += 1
                    self.core.last_command_k = None   # no command for this sample: u = 0
                self._advance()
        self.finish()

    def _advance(self) -> None:
        """One sample of the plant; /diagnostics at once when the command timeout starts, so the
        reason for u = 0 is reported when it happens (not up to a diagnostics period later)."""
        was = self.core.timed_out
        self.core.advance()
        if self.core.timed_out and not was:
            self.publish_diagnostics()

    def finish(self) -> None:
        if self.done() and not self.finished:
            self.finished = True
            self.get_logger().info(f'duration reached: {self.core.plant.t:.3f} s simulated in '
                                   f'{time.monotonic() - self.wall_start:.2f} s wall')
            self.publish_diagnostics()
            self.context.try_shutdown()   # the process exits cleanly (the launcher's --duration)

    def publish_diagnostics(self) -> None:
        c = self.core.counters
        if self.core.estop:
            level, msg = DiagnosticStatus.ERROR, 'e-stop latched: motor at zero'
        elif self.core.timed_out:
            level, msg = DiagnosticStatus.WARN, (f'command timeout: no command for '
                                                 f'{self.core.timeout_samples} samples, u = 0')
        elif c.rejected_commands:
            level, msg = DiagnosticStatus.WARN, f'rejected commands: {c.last_reject_reason}'
        else:
            level, msg = DiagnosticStatus.OK, 'running'
        wall = time.monotonic() - self.wall_start
        values = {
            'mode': 'lockstep' if self.lockstep else 'realtime',
            'sim_time': f'{self.core.plant.t:.6f}', 'wall_time': f'{wall:.3f}',
            'samples': c.samples, 'commands': c.commands, 'rejected_commands': c.rejected_commands,
            'stale_commands': c.stale_commands, 'saturated_commands': c.saturated_commands,
            'timeout_samples': c.timeout_samples, 'timeouts': c.timeouts,
            'late_commands': c.late_commands, 'estop_samples': c.estop_samples,
            'overruns': self.overruns, 'estop': self.core.estop, 'finished': self.finished,
        }
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status.append(diagnostic_status(f'{self.get_namespace().rstrip("/")}/sim: plant',
                                            self.get_namespace(), level, msg, values))
        self.pub_diag.publish(arr)

    def close(self) -> None:
        self.stop.set()
        with self.lock:
            self.lock.notify_all()
        self.thread.join(timeout=2.0)
        try:
            self.publish_diagnostics()
        except Exception:  # noqa: BLE001 - context may be gone
            pass


def main(args=None) -> int:
    return run_node(SimNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
