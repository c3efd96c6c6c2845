"""``sim`` node: the simulated Reaction Wheel Pendulum, with the rig's interface.

Publishes ``encoders`` (EncoderCounts) every h, applies the latest ``command`` (MotorCommand)
with zero-order hold, publishes ``sim/true_state`` (PlantState), serves ``sim/disturb``
(Disturb), enforces the command timeout and the latched e-stop (``estop`` topic,
std_msgs/Bool, and ``~/estop`` service, std_srvs/SetBool), reports on ``/diagnostics``
(stamped with the sim time in lockstep, like the estimator's and the controller's).

The node has no thread of its own: the loop's process runs its samples (``python -m
rwpend_loop.host sim [estimator controller]``; ``./rwpend node sim`` starts it alone, the
estimator and the controller then elsewhere, through ``encoders`` and ``command``). Two time
modes (parameter ``lockstep``):
* real time: samples on the wall clock, like the rig (the loop's pacer, absolute deadlines);
* lockstep: publishes ``/clock``; sample k waits for the command answering seq k (from the
  loop's own controller at once; from one outside ``lockstep_timeout`` s of wall time, then u = 0
  for that sample, counted -- not at all once the loop is dead and no node publishes ``command``
  any more: a controller that ended does not make the rest of the run crawl); runs as fast as
  the loop allows; identical inputs give identical
  outputs. With ``lockstep_recorder_window`` W > 0 the loop also keeps within W samples of a
  recorder outside: sample k goes out once the recorder has reported (``recorder/progress``,
  rosgraph_msgs/Clock, every :data:`rwpend_ros.qos.RECORDER_PROGRESS_EVERY` samples) the
  ``/clock`` of sample k - W, so a recorder that runs behind (starved of CPU, a slow disk) slows
  the run down instead of losing messages (the publishers keep 100 samples for a reader that
  lags: QOS_CONTROL_PUB).

All algorithms live in :mod:`rwpend_sim.sim_core` and :mod:`rwpend_model.plant`.
"""
from __future__ import annotations

import struct
import sys
import time
from functools import partial

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rosgraph_msgs.msg import Clock
from std_msgs.msg import Bool
from std_srvs.srv import SetBool

from rwpend_msgs.msg import EncoderCounts, MotorCommand, PlantState
from rwpend_msgs.srv import Disturb
from rwpend_ros.sched import thread_priority_spec
from rwpend_ros import wire
from rwpend_ros.claim import CommandClaim, format_id
from rwpend_ros.diagnostics import publish_diagnostic
from rwpend_ros.health import EXIT_LOOP_DEAD, SLOW_ADVICE, LoopHealth
from rwpend_ros.nodes import RwNode, estop_subscriptions, local_subscription
from rwpend_ros.params import ConfigError, ParameterTable, declare_rig
from rwpend_ros.paramspec import ParamSpec
from rwpend_ros.qos import (QOS_CONTROL, QOS_CONTROL_PUB, QOS_LATCHED, QOS_PROGRESS, QOS_STATUS, RECORDER_WINDOW_MAX, RECORDER_WINDOW_MIN)
from rwpend_model.rig import format_differences, rig_differences
from rwpend_ros.trace import tracer
from rwpend_ros.gate import CommandGate
from rwpend_sim.sim_core import MAX_TAP, Reading, SimCore, SimHardware

RO = partial(ParamSpec, read_only=True)

#: The simulator's parameters, all read-only (set at start): name, default, description, bounds.
PARAMS = [
    thread_priority_spec(),
    RO('lockstep', False, 'lockstep time mode: publish /clock, wait for the command of each sample'),
    RO('lockstep_timeout', 0.5, 'lockstep: wall seconds to wait for the command of a sample',
       low=0.0, low_open=True),
    RO('lockstep_recorder_window', 0, 'lockstep: samples the simulator may run ahead of the recorder '
       '(recorder/progress); 0 = no recorder to wait for (./rwpend up --lockstep --record sets 50)',
       low=0, high=RECORDER_WINDOW_MAX, constraints=f'0 or {RECORDER_WINDOW_MIN}..{RECORDER_WINDOW_MAX}'),
    RO('lockstep_recorder_timeout', 5.0, 'lockstep: wall seconds without progress from a recorder that '
       'is behind before the simulator runs on without it (warned, counted in /diagnostics: the '
       'bag may then miss messages)', low=0.0, low_open=True),
    RO('start.delay', 0.5, 'wall seconds to wait after the loop is connected, before sample 0 (for '
       'discovery to settle; skipped in lockstep when the loop\'s process awaits nothing outside)', low=0.0),
    RO('start.encoders_subscribers', 1, 'subscribers of encoders to wait for before sample 0 '
       '(2 with a recorder)', low=0),
    RO('start.true_state_subscribers', 0, 'subscribers of sim/true_state to wait for before sample 0',
       low=0),
    RO('start.command_subscribers', 0, 'subscribers of command besides the simulator to wait for '
       'before sample 0: the recorder of a stack whose controller runs in another process, and a '
       'separate estimator (./rwpend up --record sets it), so that the bag has the commands from '
       'the first sample', low=0),
    RO('start.state_subscribers', 0, 'lockstep: subscribers of state (the controller) to wait for '
       'before sample 0', low=0),
    RO('start.first_command_timeout', 10.0, 'lockstep: wall seconds sample 0 waits for its command '
       '(start-up under load; later samples wait lockstep_timeout)', low=0.0, low_open=True),
    RO('command_timeout_samples', 3, 'samples without a fresh command before u = 0', low=1),
    RO('claim_timeout_samples', 500, 'samples without any command of the controller that claimed the '
       'rig before another controller may claim it (rwpend_ros.claim)', low=1),
    RO('initial.theta', 0.0, 'initial pendulum angle (rad, 0 hanging, pi upright)'),
    RO('initial.theta_dot', 0.0, 'initial pendulum angular velocity (rad/s)'),
    RO('initial.wheel_angle', 0.0, 'initial absolute wheel angle (rad)'),
    RO('initial.wheel_rate', 0.0, 'initial absolute wheel angular velocity (rad/s)'),
    RO('friction', True, 'rotor friction (3.17) with stiction and pendulum-axis friction'),
    RO('motor_lag', True, 'first-order current lag T_e'),
    RO('pwm', True, 'PWM duty quantization of the command'),
    RO('back_emf', True, 'back-EMF cut-off (2.13)'),
    RO('bracket', False, 'Chapter 3 configuration (Fig. 3.1): pendulum locked on the fixed bracket, '
       'wheel free'),
    RO('torque_meter', False, 'with bracket: the wheel held by a torque meter (Experiment 2); it reads '
       'k_u (torque - friction) of sim/true_state'),
    RO('publish_true_state', True, 'publish sim/true_state every sample'),
    RO('taps.times', [-1.0], 'scripted taps: simulated times (s); [-1.0] = none',
       constraints='each >= 0, or [-1.0]'),
    RO('taps.sizes', [0.0], 'scripted taps: theta_dot jumps (rad/s), one per time',
       constraints=f'as many as taps.times, each |size| <= {MAX_TAP:g}'),
    RO('torques.times', [-1.0], 'scripted torques on the pendulum: simulated start times (s); '
       '[-1.0] = none', constraints='each >= 0, or [-1.0]'),
    RO('torques.sizes', [0.0], 'scripted torques: control units, one per time',
       constraints='as many as torques.times'),
    RO('torques.durations', [0.0], 'scripted torques: seconds, one per time',
       constraints='as many as torques.times, each >= 0'),
    RO('duration', 0.0, 'stop after this many simulated seconds (0 = run until stopped)', low=0.0),
    RO('frame_id', 'rwpend', 'frame_id of the published headers'),
    RO('diagnostics_period', 1.0, 'seconds between /diagnostics messages', low=0.0, low_open=True),
    RO('loop_dead_after', 2.0, 's of command timeout, after the loop had run, before the loop is '
       'reported dead (an ERROR on /diagnostics; exit status 3 if still dead at the end)',
       low=0.0, low_open=True),
]


def checked_recorder_window(window: int) -> int:
    """``lockstep_recorder_window`` as given, when it is 0 or in the allowed range."""
    if not (window == 0 or RECORDER_WINDOW_MIN <= window <= RECORDER_WINDOW_MAX):
        raise ConfigError(f'lockstep_recorder_window must be 0 or in {RECORDER_WINDOW_MIN}..'
                          f'{RECORDER_WINDOW_MAX} (samples), got {window}')
    return window


def make_core(rig, p: dict) -> SimCore:
    """The simulated plant of ``rig`` from the node's parameters ``p``: its initial state, the
    effects modelled, the command timeout, the scripted taps and torques. A bad value is a
    ConfigError."""
    try:
        core = SimCore(rig, command_timeout_samples=p['command_timeout_samples'],
                       theta=p['initial.theta'], theta_dot=p['initial.theta_dot'],
                       wheel_angle=p['initial.wheel_angle'], wheel_rate=p['initial.wheel_rate'],
                       friction=p['friction'], motor_lag=p['motor_lag'], pwm=p['pwm'],
                       back_emf=p['back_emf'], bracket=p['bracket'],
                       rotor_locked=p['torque_meter'])
        times, sizes = list(p['taps.times']), list(p['taps.sizes'])
        if times == [-1.0]:
            times, sizes = [], []
        core.schedule_taps(times, sizes)
        times, sizes, durs = (list(p[f'torques.{k}']) for k in ('times', 'sizes', 'durations'))
        if times == [-1.0]:
            times, sizes, durs = [], [], []
        core.schedule_torques(times, sizes, durs)
    except (ValueError, TypeError) as exc:
        raise ConfigError(str(exc)) from exc
    return core


class SimNode(RwNode):
    #: the loop's process runs the samples (rwpend_loop.host): no timer of its own here
    #: (rwpend_ros.nodes.SlackTimer); :meth:`publish_sample` is called after each sample's
    #: command is written
    hosted = True

    def __init__(self, loop_lock, external_command: bool = True) -> None:
        """``loop_lock``: the lock of the loop's process (rwpend_loop.host.LoopLock);
        ``external_command``: commands also come from the ``command`` topic (a controller
        outside the loop)."""
        #: called with the new e-stop state, the loop's lock held, when it changes (the loop's
        #: process gives its controller's on_estop_state)
        self.on_estop_change = None
        super().__init__('sim', loop_lock=loop_lock)
        self.param_table = ParameterTable(self)
        self.rig = declare_rig(self.param_table)   # the plant's physical truth
        model = declare_rig(self.param_table, 'model_rig.', ': the rig YAML the estimator and controller '
                            'read (./rwpend up --rig), for the report of where the truth (rig.*) differs')
        #: where the truth differs from the model, for the start-up line and /diagnostics ('' = nowhere)
        self.truth_differs = format_differences(rig_differences(model, self.rig))
        p = self.param_table.declare(PARAMS)
        window = checked_recorder_window(p['lockstep_recorder_window'])
        self.core = make_core(self.rig, p)
        self.p = p
        self.h = self.rig.sample_period
        self.period_ns = int(round(self.h * 1e9))
        self.lockstep = bool(p['lockstep'])
        # in lockstep a sample without its command costs lockstep_timeout of wall time: the
        # verdicts count such samples (the first-seconds check only judges real time)
        self.health = LoopHealth(p['lockstep_timeout'] if self.lockstep else self.h,
                                 dead_after_s=p['loop_dead_after'])
        #: the loop's lock (one for every node of the loop's process; a condition the lockstep
        #: loop waits on for an external command or the recorder's progress)
        self.lock = loop_lock.lock
        self.hw = SimHardware(self.core)
        self.finished = False

        self._create_interfaces(external_command)
        self._init_recorder_wait(window)

        self.frame_id = p['frame_id']
        self.wall_start = time.monotonic()
        self.overruns = 0
        self.malformed_commands = 0
        self.steps = 0                  # samples integrated
        #: what sample 0 still waits for (the loop's process says it on /diagnostics), '' when none
        self.waiting_for = ''
        self.trace = tracer('sim')      # None unless RWPEND_TRACE is set (profiling)
        mode = 'lockstep' if self.lockstep else 'real time'
        self.get_logger().info(f'simulated rig: h = {self.h * 1e3:g} ms, {mode}, '
                               f'a = {self.rig.a:.3f}, b_p = {self.rig.b_p:.4f}, b_r = {self.rig.b_r:.2f}; '
                               + (f'its truth differs from the rig YAML of the estimator and controller: '
                                  f'{self.truth_differs}' if self.truth_differs else 'truth = the rig YAML'))

    def _create_interfaces(self, external_command: bool) -> None:
        """The node's publishers, subscriptions and services, the command claim and the gate
        every command goes through to the plant."""
        self.pub_enc = self.create_publisher(EncoderCounts, 'encoders', QOS_CONTROL_PUB)
        self.pub_true = self.create_publisher(PlantState, 'sim/true_state', QOS_CONTROL_PUB)
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', QOS_STATUS)
        self.pub_clock = self.create_publisher(Clock, '/clock', QOS_CONTROL_PUB) if self.lockstep else None
        # the per-sample path takes and publishes wire bytes (rwpend_ros.wire; PERFORMANCE.md)
        self.sub_cmd = (local_subscription(self, MotorCommand, 'command', self.on_command, QOS_CONTROL,
                                           sender=wire.command_sender)
                        if external_command else None)
        #: one controller at a time (rwpend_ros.claim)
        try:
            self.claim = CommandClaim(self.p['claim_timeout_samples'])
        except ValueError as exc:
            raise ConfigError(f'claim_timeout_samples {exc}') from exc
        #: every command goes to the plant through the gate (claim, freshness, loop health)
        self.gate = CommandGate(self.hw, self.claim, self.health)
        estop_subscriptions(self, self.on_estop_topic)
        #: the plant's e-stop as it is (latched): the controller and the console follow it
        self.pub_estop_state = self.create_publisher(Bool, 'estop/state', QOS_LATCHED)
        self.pub_estop_state.publish(Bool(data=False))
        self.create_service(Disturb, 'sim/disturb', self.on_disturb)
        self.create_service(SetBool, '~/estop', self.on_estop_service)

    def _init_recorder_wait(self, window: int) -> None:
        """Lockstep with a recorder outside: how far ahead of it the simulator may run
        (``window`` samples) and the counts of its waits; the ``recorder/progress``
        subscription where it waits."""
        #: lockstep: samples this simulator may run ahead of the recorder (0: it does not wait)
        self.recorder_window = int(window) if self.lockstep else 0
        self.recorder_k = -1            # the newest sample the recorder reported (its /clock)
        self.recorder_wall = 0.0        # wall time (monotonic) of its newest report
        self.recorder_holds = 0         # samples that waited for the recorder
        self.recorder_hold_s = 0.0      # wall seconds they waited
        self.recorder_given_up = False  # the recorder stopped reporting: the run went on without it
        self.malformed_progress = 0
        if self.recorder_window:
            self.create_subscription(Clock, 'recorder/progress', self.on_recorder_progress,
                                     QOS_PROGRESS, raw=True)

    # ------------------------------------------------------------ callbacks
    def on_command(self, data: bytes) -> None:
        """A command from the ``command`` topic (wire bytes), offered to the gate; the loop
        integrates the interval it answers at the next instant (real time) or as soon as it is
        in (lockstep: the loop waits on the lock, notified here)."""
        try:
            seq, u, source, release = wire.unpack_command_sender(data)
        except (struct.error, IndexError) as exc:   # truncated bytes: counted, nothing else changes
            with self.lock:
                self.malformed_commands += 1
                self.core.counters.rejected_commands += 1
                self.core.counters.last_reject_reason = f'malformed command: {exc}'
            return
        if self.trace is not None:
            self.trace('sim.rx', seq)
        with self.lock:
            ok = self._offer(source, seq, u, release)
            if ok:
                self._report(self.gate.take_event())
            self.lock.notify_all()           # a lockstep loop waiting for this command

    def _offer(self, source: int, seq: int, u: float, release: bool) -> bool:
        """Lock held: the command (seq, u) of controller ``source`` to the plant, if that
        controller may drive the rig (rwpend_ros.claim); True when taken. A release puts the
        motor at zero now. A change of the claim is said at once (log, /diagnostics)."""
        taken = self.gate.offer(source, seq, u, release)
        event = self.claim.event
        if event == 'refused':
            self.get_logger().warn(
                f'command from controller {format_id(source)} refused: the rig is claimed by '
                f'{format_id(self.claim.holder)} (publishers of command: {self._command_publishers()})')
        elif event is not None:
            self.get_logger().info(f'rig {event} by controller {format_id(source)}')
        if event is not None:
            self.publish_diagnostics()
        return taken

    def _command_publishers(self) -> str:
        """The nodes publishing ``command`` in the graph, for the report of an intruder."""
        try:
            infos = self.get_publishers_info_by_topic(self.sub_cmd.topic_name)
        except Exception as exc:  # noqa: BLE001 - a report, never a failure
            return f'unknown ({exc})'
        return ', '.join(sorted(f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in infos)) or 'none'

    def on_recorder_progress(self, data: bytes) -> None:
        """The recorder's progress (the newest ``/clock`` it took, wire bytes): a sample the loop
        holds for it goes out once it is within ``lockstep_recorder_window`` samples."""
        try:
            k = wire.unpack_clock_ns(data) // self.period_ns
        except (struct.error, IndexError, ValueError):
            with self.lock:
                self.malformed_progress += 1
            return
        with self.lock:
            self.recorder_wall = time.monotonic()
            if k > self.recorder_k:
                self.recorder_k = k
            self.lock.notify_all()           # a lockstep loop holding a sample for it

    def recorder_behind(self, k: int) -> bool:
        """Lock held: sample k must wait for the recorder (``lockstep_recorder_window``)."""
        return bool(self.recorder_window) and k - self.recorder_window > self.recorder_k

    def set_estop(self, on: bool) -> str:
        with self.lock:
            changed = self.core.estop != on
            self.core.estop = on
            if changed:
                self.pub_estop_state.publish(Bool(data=bool(on)))
                if self.on_estop_change is not None:
                    # a controller of the loop's process hears it before the next sample (its
                    # estop/state subscription would take a DDS round trip: in lockstep, many samples)
                    self.on_estop_change(bool(on))
                # reported before any sample taken with the new state goes out (the lock holds
                # the loop): in a bag the report comes first
                self.publish_diagnostics()
        if changed:
            # one call site per severity: rclpy refuses a severity change at a call site
            if on:
                self.get_logger().warn('E-STOP raised: motor held at zero')
            else:
                self.get_logger().info('e-stop cleared')
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
    def publish_sample(self, stamp_ns: int, r: Reading) -> bytes:
        """Sample ``r`` (taken by the loop) as wire bytes: encoders, then /clock (lockstep), then
        sim/true_state; returns the encoders' bytes."""
        seq = r.seq
        if self.trace is not None:
            self.trace('sim.pub', seq)
        sec, nsec = divmod(stamp_ns, 1_000_000_000)
        header = wire.pack_header(sec, nsec, self.frame_id)
        enc = wire.pack_encoders(header, seq, r.pendulum_counts, r.motor_counts)
        self.pub_enc.publish(enc)
        if self.pub_clock is not None:
            # after the encoder sample: the sample is on the loop's critical path, /clock (three
            # readers) is not; a node may see sample k before its clock reads t_k (the controller's
            # state watchdog takes the stamp then, rwpend_control.safety)
            self.pub_clock.publish(wire.pack_clock(sec, nsec))
        if self.p['publish_true_state']:
            s = r.truth
            self.pub_true.publish(wire.pack_plant_state(
                header, seq, s.command_seq, s.theta, s.theta_dot, s.wheel_angle, s.wheel_rate,
                s.u_applied, s.torque, s.friction, s.disturbance, s.stuck, s.timed_out))
        return enc

    def done(self) -> bool:
        d = self.p['duration']
        return d > 0 and self.core.plant.t >= d - 1e-9

    def _report(self, event: str | None) -> None:
        """The loop's health changed (rwpend_ros.health): said at once, in the log and on
        /diagnostics."""
        if event is None:
            return
        log = self.get_logger()
        if event == 'dead':
            log.error(self.health.dead_reason(self.h if self.lockstep else None))
        elif event == 'alive':
            log.info('the loop is answering again: commands are fresh')
        elif event == 'slow' and not self.lockstep:
            log.warn(f'{self.health.verdict}: this machine does not keep h = {self.h * 1e3:g} ms with '
                     f'this layout; {SLOW_ADVICE}')
        self.publish_diagnostics()

    def exit_status(self) -> int:
        """:data:`rwpend_ros.health.EXIT_LOOP_DEAD` when the loop was dead at the end."""
        if self.health.dead:
            print(f'sim: {self.health.dead_reason(self.h if self.lockstep else None)} (at the end of the run)', file=sys.stderr, flush=True)
            return EXIT_LOOP_DEAD
        return 0

    def finish(self) -> None:
        if self.done() and not self.finished:
            self.finished = True
            self.get_logger().info(f'duration reached: {self.core.plant.t:.3f} s simulated in '
                                   f'{time.monotonic() - self.wall_start:.2f} s wall')
            self.publish_diagnostics()   # finished: the runner ends the process (rwpend_ros.runner)

    def diagnostics_stamp_ns(self) -> int:
        """The stamp of /diagnostics: lockstep, the sim time of the plant (t_k of the sample
        the plant is at, the stamp of sample k and of the /clock that goes with it), so every
        node of a lockstep run stamps /diagnostics on the one simulated clock (the estimator
        and the controller take their ROS time from the samples); real time, the ROS clock
        (wall time)."""
        if self.lockstep:
            return self.core.k * self.period_ns
        return self.get_clock().now().nanoseconds

    def publish_diagnostics(self) -> None:
        c = self.core.counters
        if self.core.estop:
            level, msg = DiagnosticStatus.ERROR, 'e-stop latched: motor at zero'
        elif self.health.dead:
            level, msg = DiagnosticStatus.ERROR, self.health.dead_reason(self.h if self.lockstep else None)
        elif self.core.timed_out:
            level, msg = DiagnosticStatus.WARN, (f'command timeout: no command for '
                                                 f'{self.core.timeout_samples} samples, u = 0')
        elif self.claim.intruding(self.core.k, int(round(1.0 / self.h))):
            level, msg = DiagnosticStatus.WARN, (
                f'commands of controller {format_id(self.claim.intruder)} refused: the rig is claimed by '
                f'{format_id(self.claim.holder)}')
        elif c.rejected_commands:
            level, msg = DiagnosticStatus.WARN, f'rejected commands: {c.last_reject_reason}'
        elif self.waiting_for:
            level, msg = DiagnosticStatus.OK, f'waiting before sample 0 for {self.waiting_for}'
        elif self.recorder_given_up:
            level, msg = DiagnosticStatus.WARN, ('lockstep ran on without the recorder (no progress '
                                                 'from it): the bag may miss messages')
        else:
            level, msg = DiagnosticStatus.OK, 'running' + (' (plant truth differs from the rig YAML: '
                                                         'truth_vs_model)' if self.truth_differs else '')
        wall = time.monotonic() - self.wall_start
        values = {
            'mode': 'lockstep' if self.lockstep else 'realtime',
            'sim_time': f'{self.core.plant.t:.6f}', 'wall_time': f'{wall:.3f}',
            'samples': c.samples, 'commands': c.commands, 'rejected_commands': c.rejected_commands,
            'stale_commands': c.stale_commands, 'old_commands': c.old_commands,
            'saturated_commands': c.saturated_commands,
            'timeout_samples': c.timeout_samples, 'timeouts': c.timeouts,
            'late_commands': c.late_commands, 'estop_samples': c.estop_samples,
            'overruns': self.overruns, 'malformed_commands': self.malformed_commands,
            'estop': self.core.estop, 'finished': self.finished,
            **({'recorder_window': self.recorder_window, 'recorder_holds': self.recorder_holds,
                'recorder_hold_s': f'{self.recorder_hold_s:.3f}', 'recorder_given_up': self.recorder_given_up,
                'malformed_progress': self.malformed_progress}
               if self.p['lockstep_recorder_window'] and self.lockstep else {}),
            'command_order': self.sub_cmd.summary() if self.sub_cmd is not None else 'in the loop',
            **self.claim.values(),
            'truth_vs_model': self.truth_differs or 'same',
            **self.health.values(self.h if self.lockstep else None),
        }
        publish_diagnostic(self.pub_diag, self.diagnostics_stamp_ns(),
                           f'{self.get_namespace().rstrip("/")}/sim: plant', self.get_namespace(), level, msg,
                           values)

    def close(self) -> None:
        try:
            self.publish_diagnostics()
        except Exception:  # noqa: BLE001 - context may be gone
            pass
