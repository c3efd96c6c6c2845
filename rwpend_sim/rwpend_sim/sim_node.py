"""``sim`` node: the simulated Reaction Wheel Pendulum, with the rig's interface.

Publishes ``encoders`` (EncoderCounts) every h, applies the latest ``command`` (MotorCommand)
with zero-order hold, publishes ``sim/true_state`` (PlantState), serves ``sim/disturb``
(Disturb), enforces the command timeout and the latched e-stop (``estop`` topic,
std_msgs/Bool, and ``~/estop`` service, std_srvs/SetBool), reports on ``/diagnostics``
(stamped with the sim time in lockstep, like the estimator's and the controller's).

Two time modes (parameter ``lockstep``):
* real time: samples on the wall clock, like the rig (a thread with absolute deadlines);
* lockstep: publishes ``/clock``; for sample k it waits for the command answering seq k
  (``lockstep_timeout`` s of wall time, then u = 0 for that sample, counted) before
  integrating; runs as fast as the loop allows; identical inputs give identical outputs.
  With ``lockstep_recorder_window`` W > 0 it also keeps within W samples of the recorder: sample
  k goes out once the recorder has reported (``recorder/progress``, rosgraph_msgs/Clock, every
  :data:`rwpend_ros.qos.RECORDER_PROGRESS_EVERY` samples) the ``/clock`` of sample k - W, so a
  recorder that runs behind (starved of CPU, a slow disk) slows the run down instead of losing
  messages (the publishers keep 100 samples for a reader that lags: QOS_CONTROL_PUB).

All algorithms live in :mod:`rwpend_sim.sim_core` and :mod:`rwpend_model.plant`.
"""
from __future__ import annotations

import struct
import sys
import threading
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
from rwpend_ros.nodes import RwNode, SlackTimer, estop_subscriptions, local_subscription
from rwpend_ros.params import ConfigError, ParameterTable, declare_rig
from rwpend_ros.paramspec import ParamSpec
from rwpend_ros.qos import (QOS_CONTROL, QOS_CONTROL_PUB, QOS_LATCHED, QOS_PROGRESS, QOS_STATUS, RECORDER_WINDOW_MAX, RECORDER_WINDOW_MIN)
from rwpend_ros.runner import run_node
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
    RO('start.delay', 0.5, 'wall seconds to wait after the loop is connected, before sample 0', low=0.0),
    RO('start.encoders_subscribers', 1, 'subscribers of encoders to wait for before sample 0 '
       '(2 with a recorder)', low=0),
    RO('start.true_state_subscribers', 0, 'subscribers of sim/true_state to wait for before sample 0',
       low=0),
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


class SimNode(RwNode):
    def __init__(self, loop_lock=None, hosted: bool = False, external_command: bool = True) -> None:
        """``loop_lock``: the loop's lock when the loop's process hosts this node
        (rwpend_loop.host), else None. ``hosted``: the loop's process
        runs the samples (no sample thread here; :meth:`publish_sample` is called after each
        sample's command is written); ``external_command``: commands also come from the
        ``command`` topic (a controller outside the loop)."""
        self.hosted = bool(hosted)
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
        window = p['lockstep_recorder_window']
        if not (window == 0 or RECORDER_WINDOW_MIN <= window <= RECORDER_WINDOW_MAX):
            raise ConfigError(f'lockstep_recorder_window must be 0 or in {RECORDER_WINDOW_MIN}..'
                              f'{RECORDER_WINDOW_MAX} (samples), got {window}')
        try:
            self.core = SimCore(self.rig, command_timeout_samples=p['command_timeout_samples'],
                                theta=p['initial.theta'], theta_dot=p['initial.theta_dot'],
                                wheel_angle=p['initial.wheel_angle'], wheel_rate=p['initial.wheel_rate'],
                                friction=p['friction'], motor_lag=p['motor_lag'], pwm=p['pwm'],
                                back_emf=p['back_emf'], bracket=p['bracket'],
                                rotor_locked=p['torque_meter'])
            times, sizes = list(p['taps.times']), list(p['taps.sizes'])
            if times == [-1.0]:
                times, sizes = [], []
            self.core.schedule_taps(times, sizes)
            times, sizes, durs = (list(p[f'torques.{k}']) for k in ('times', 'sizes', 'durations'))
            if times == [-1.0]:
                times, sizes, durs = [], [], []
            self.core.schedule_torques(times, sizes, durs)
        except (ValueError, TypeError) as exc:
            raise ConfigError(str(exc)) from exc
        self.p = p
        self.h = self.rig.sample_period
        self.period_ns = int(round(self.h * 1e9))
        self.lockstep = bool(p['lockstep'])
        # in lockstep a sample without its command costs lockstep_timeout of wall time: the
        # verdicts count such samples (the first-seconds check only judges real time)
        self.health = LoopHealth(p['lockstep_timeout'] if self.lockstep else self.h,
                                 dead_after_s=p['loop_dead_after'])
        #: the loop's lock: the host's (one for every node of the loop) or this node's own
        self.lock = loop_lock.lock if self.hosted else threading.Condition()
        self.stop = threading.Event()
        self.hw = SimHardware(self.core)
        self.finished = False

        self.pub_enc = self.create_publisher(EncoderCounts, 'encoders', QOS_CONTROL_PUB)
        self.pub_true = self.create_publisher(PlantState, 'sim/true_state', QOS_CONTROL_PUB)
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', QOS_STATUS)
        self.pub_clock = self.create_publisher(Clock, '/clock', QOS_CONTROL_PUB) if self.lockstep else None
        # the per-sample path takes and publishes wire bytes (rwpend_ros.wire; PERFORMANCE.md)
        self.sub_cmd = (local_subscription(self, MotorCommand, 'command', self.on_command, QOS_CONTROL,
                                           sender=wire.command_sender)
                        if external_command or not self.hosted else None)
        #: one controller at a time (rwpend_ros.claim)
        try:
            self.claim = CommandClaim(p['claim_timeout_samples'])
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
        # in the loop's slack: after a command is applied, not while a command waits (19.)
        self.diag_timer = SlackTimer(self, p['diagnostics_period'], self.publish_diagnostics)
        #: lockstep: samples this simulator may run ahead of the recorder (0: it does not wait)
        self.recorder_window = int(window) if self.lockstep else 0
        self.recorder_k = -1            # the newest sample the recorder reported (its /clock)
        self.recorder_wall = 0.0        # wall time (monotonic) of its newest report
        self.held_for_recorder = False  # sample core.k waits for the recorder
        self.hold_wall = 0.0            # ... since
        self.recorder_holds = 0         # samples that waited for the recorder
        self.recorder_hold_s = 0.0      # wall seconds they waited
        self.recorder_given_up = False  # the recorder stopped reporting: the run went on without it
        self.malformed_progress = 0
        if self.recorder_window:
            self.create_subscription(Clock, 'recorder/progress', self.on_recorder_progress,
                                     QOS_PROGRESS, raw=True)

        self.frame_id = p['frame_id']
        self.wall_start = time.monotonic()
        self.overruns = 0
        self.malformed_commands = 0
        #: seq of the published sample whose command is awaited (the plant integrates
        #: [t_k, t_k+1) as soon as command k arrives), None when there is none
        self.awaiting: int | None = None
        self.steps = 0                  # samples integrated
        self.step_wall = time.monotonic()   # lockstep: wall time of the newest sample
        self.trace = tracer('sim')      # None unless RWPEND_TRACE is set (profiling)
        self.thread = None
        if not self.hosted:
            self.thread = threading.Thread(target=self._run_loop, name='sim-loop', daemon=True)
            self.thread.start()
        mode = 'lockstep' if self.lockstep else 'real time'
        self.get_logger().info(f'simulated rig: h = {self.h * 1e3:g} ms, {mode}, '
                               f'a = {self.rig.a:.3f}, b_p = {self.rig.b_p:.4f}, b_r = {self.rig.b_r:.2f}; '
                               + (f'its truth differs from the rig YAML of the estimator and controller: '
                                  f'{self.truth_differs}' if self.truth_differs else 'truth = the rig YAML'))

    # ------------------------------------------------------------ callbacks
    def on_command(self, data: bytes) -> None:
        """A command (wire bytes). When it answers the awaited sample k, the plant is integrated
        over [t_k, t_k+1) at once, here: in real time the next sample is then ready to go out at
        its instant; in lockstep the next sample goes out from here, without waking another
        thread (the loop thread only watches the lockstep timeout)."""
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
            if ok and self.awaiting is not None and self.core.u_seq >= self.awaiting:
                self._step()
            if self.hosted:
                self.lock.notify_all()       # a lockstep loop waiting for this command
        self.diag_timer.sample_done()

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
        """The recorder's progress (the newest ``/clock`` it took, wire bytes): a sample held
        for it goes out once it is within ``lockstep_recorder_window`` samples."""
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
            if self.held_for_recorder and not self._recorder_behind():
                self._release_hold()
                if not self.stop.is_set():
                    self._publish_lockstep()

    def _recorder_behind(self) -> bool:
        """Lock held: sample core.k must wait for the recorder."""
        return bool(self.recorder_window) and self.core.k - self.recorder_window > self.recorder_k

    def _release_hold(self) -> None:
        self.held_for_recorder = False
        self.recorder_hold_s += time.monotonic() - self.hold_wall

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
    def publish_sample(self, stamp_ns: int, reading: Reading | None = None) -> bytes:
        """Sample core.k (or ``reading``, taken by the loop) as wire bytes: encoders, then /clock
        (lockstep), then sim/true_state; returns the encoders' bytes."""
        r = self.hw.read() if reading is None else reading
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
        if not self.hosted:
            self.awaiting = seq
        return enc

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
                        >= self.p['start.state_subscribers']
                        # the recorder this run keeps pace with takes /clock (its progress)
                        and (not self.recorder_window or self.pub_clock.get_subscription_count() > 0)))):
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
        """Sample k goes out at t0 + k h (absolute deadlines on the monotonic clock). The plant is
        integrated over [t_k, t_k+1) when command k arrives (:meth:`on_command`), or at t_k+1 with
        the command held then if it did not: so at each instant only the publishing is left."""
        self.wait_for_loop(need_command=False)
        period_ns = self.period_ns
        t0_ros = self.get_clock().now().nanoseconds
        t0 = time.monotonic_ns()
        k = 0
        while not self.stop.is_set():
            if not self._tick(t0_ros + k * period_ns, t0 + k * period_ns):
                break
            k += 1
            delay = t0 + k * period_ns - time.monotonic_ns()
            if delay > 0:
                time.sleep(delay / 1e9)
            elif delay < -period_ns:
                self.overruns += 1
        self.finish()

    def _tick(self, stamp_ns: int, tick_ns: int) -> bool:
        """The sample instant: the held command if command k-1 did not come, then sample k;
        False when the run is done."""
        with self.lock:
            if self.awaiting is not None:      # command k-1 not in time: the held one
                self.awaiting = None
                self._advance(late=True)
            if self.done():
                return False
            if self.trace is not None:
                self.trace('sim.tick', self.core.k, tick_ns)
            self.publish_sample(stamp_ns)
        return True

    def _step(self, late: bool = False) -> None:
        """Lock held, command for the awaited sample in (or, ``late``, given up on): integrate;
        lockstep: the next sample."""
        self.awaiting = None
        self._advance(late)
        self.steps += 1
        if self.lockstep:
            if self.done() or self.stop.is_set():
                self.lock.notify_all()             # the loop thread finishes
            elif self._recorder_behind():          # on_recorder_progress publishes it
                self.held_for_recorder = True
                self.hold_wall = time.monotonic()
                self.recorder_holds += 1
            else:
                self._publish_lockstep()

    def _publish_lockstep(self) -> None:
        stamp = self.core.k * self.period_ns
        self.step_wall = time.monotonic()
        if self.trace is not None:
            self.trace('sim.tick', self.core.k)
        self.publish_sample(stamp)

    def loop_lockstep(self) -> None:
        """Publishes sample 0, then watches: each command answering the awaited sample steps
        the plant and publishes the next (:meth:`on_command`); a sample whose command does not
        come within ``lockstep_timeout`` wall seconds (``start.first_command_timeout`` for
        sample 0) is integrated with u = 0 and counted late. A sample held for the recorder
        (``lockstep_recorder_window``) waits for its progress; after
        ``lockstep_recorder_timeout`` s without any, the run goes on without waiting for it."""
        self.wait_for_loop(need_command=True)
        timeout = self.p['lockstep_timeout']
        with self.lock:
            self._publish_lockstep()
            while not self.stop.is_set() and not self.done():
                if self.held_for_recorder:
                    limit = self.p['lockstep_recorder_timeout']
                    remaining = max(self.recorder_wall, self.hold_wall) + limit - time.monotonic()
                    if remaining > 0:
                        self.lock.wait(min(remaining, timeout))
                        continue
                    self.get_logger().error(
                        f'lockstep: the recorder reported no progress for {limit:g} s while '
                        f'{self.core.k - self.recorder_k} samples behind; running on without waiting '
                        'for it (the bag may miss messages)')
                    self.recorder_window = 0
                    self.recorder_given_up = True
                    self._release_hold()
                    self._publish_lockstep()
                    continue
                limit = timeout if self.core.k else self.p['start.first_command_timeout']
                remaining = self.step_wall + limit - time.monotonic()
                if remaining > 0:
                    # notified at stop and at the end only (a step does not wake this thread):
                    # look again at least every lockstep_timeout
                    self.lock.wait(min(remaining, timeout))
                    continue
                if self.core.k == 0:
                    self.get_logger().warn('lockstep: no command for sample 0 within '
                                           f"{self.p['start.first_command_timeout']:g} s; running with u = 0")
                self.core.counters.late_commands += 1
                self.core.no_command()            # no command for this sample: u = 0
                self._step(late=True)
        self.finish()

    def _advance(self, late: bool = False) -> None:
        """One sample of the plant (``late``: its command did not come in time); /diagnostics at
        once when the command timeout starts, so the reason for u = 0 is reported when it
        happens (not up to a diagnostics period later), and when the loop's health changes."""
        was = self.core.timed_out
        self.gate.interval(late)
        event = self.gate.take_event()
        if event is not None:
            self._report(event)
        elif self.core.timed_out and not was:
            self.publish_diagnostics()

    def _report(self, event: str | None) -> None:
        """The loop's health changed (rwpend_ros.health): said at once, in the log and on
        /diagnostics."""
        if event is None:
            return
        log = self.get_logger()
        if event == 'dead':
            log.error(self.health.dead_reason())
        elif event == 'alive':
            log.info('the loop is answering again: commands are fresh')
        elif event == 'slow' and not self.lockstep:
            log.warn(f'{self.health.verdict}: this machine does not keep h = {self.h * 1e3:g} ms with '
                     f'this layout; {SLOW_ADVICE}')
        self.publish_diagnostics()

    def exit_status(self) -> int:
        """:data:`rwpend_ros.health.EXIT_LOOP_DEAD` when the loop was dead at the end."""
        if self.health.dead:
            print(f'sim: {self.health.dead_reason()} (at the end of the run)', file=sys.stderr, flush=True)
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
            level, msg = DiagnosticStatus.ERROR, self.health.dead_reason()
        elif self.core.timed_out:
            level, msg = DiagnosticStatus.WARN, (f'command timeout: no command for '
                                                 f'{self.core.timeout_samples} samples, u = 0')
        elif self.claim.intruding(self.core.k, int(round(1.0 / self.h))):
            level, msg = DiagnosticStatus.WARN, (
                f'commands of controller {format_id(self.claim.intruder)} refused: the rig is claimed by '
                f'{format_id(self.claim.holder)}')
        elif c.rejected_commands:
            level, msg = DiagnosticStatus.WARN, f'rejected commands: {c.last_reject_reason}'
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
            **self.health.values(),
        }
        publish_diagnostic(self.pub_diag, self.diagnostics_stamp_ns(),
                           f'{self.get_namespace().rstrip("/")}/sim: plant', self.get_namespace(), level, msg,
                           values)

    def close(self) -> None:
        self.stop.set()
        with self.lock:
            self.lock.notify_all()
        if self.thread is not None:
            self.thread.join(timeout=2.0)
        try:
            self.publish_diagnostics()
        except Exception:  # noqa: BLE001 - context may be gone
            pass


def main(args=None) -> int:
    return run_node(SimNode, args)


if __name__ == '__main__':
    raise SystemExit(main())
