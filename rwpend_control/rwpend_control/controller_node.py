"""``controller`` node: state estimate -> motor command, every sample.

Subscribes ``state`` (StateEstimate); publishes for every state sample ``command``
(MotorCommand: seq echoes the state's seq, header.stamp = the state's stamp, or now if it is
zero) and ``controller/status`` (ControllerStatus) every ``status_every`` samples and at once
on every change of mode or law.  Service ``~/set_mode`` (= ``controller/set_mode``, SetMode).
``/diagnostics`` once a second.

Parameters (all changeable at runtime, validated in the on-set callback -- the reason comes
back to the caller and the old values stay -- and applied in the post-set callback):

* ``mode``: off, wheel_velocity, wheel_angle, balance, swingup, auto (kept in sync with the
  service and with the controller's own switches).
* gains: ``balance.kpp/kdp/kpr/kdr``, ``balance.rate_ref``, ``patch.kpp/kdp/kdr``,
  ``swingup.c_e/c_v/kick``, ``wheel.kp/ki/ref``, ``wheel_angle.kpr/kdr/ref``, ``theta_s``,
  ``theta_0``, ``catch_region``, ``friction_compensation`` (off|model|estimate),
  ``friction_deadband``, ``allow_wheel_drift``.  A gain not given at start is designed from
  the design parameters ``<group>.design.*`` (e.g. ``balance.design.omega0: 1.5wp``); changing
  a design parameter later redesigns its group and updates the gain parameters.
* ``law.file`` (read-only): a law of one's own for mode ``law`` -- a ``.py`` file or
  ``package.module:Name`` (:mod:`rwpend_control.user_law`); ``law.params``: a JSON object of
  values it gets (the lab's designed gains).  A law that cannot be loaded stops the node at start
  with the reason; one that raises or returns a non-finite u later gives u = 0 and mode off.
* ``status_every`` (samples, >= 1).
* safety (:mod:`rwpend_control.safety`): ``state_timeout_samples`` (no new state for this many
  h, + h/2, on the node's clock -- sim time in lockstep -> one zero command answering seq + 1, fault
  "stale state" in controller/status and /diagnostics, until the next state),
  ``wheel_speed_limit`` (rad/s of the motor, below the back-EMF cut-off (2.13)) with
  ``wheel_speed_action`` (brake | off), ``max_saturation_time`` (s) with ``saturation_action``
  (off | swingup | auto).

A state with a new re-synchronisation of the estimator (StateEstimate.resyncs changed) and a
state stream resuming after stale start the current mode afresh (:mod:`rwpend_control.supervisor`:
``auto`` swings up again if the pendulum fell, ``balance`` recaptures its wheel reference,
``wheel_velocity`` resets its integrator), reported as a switch and counted (``fresh_starts``).

Faults never stop the node: a refused state is counted and answered with u = 0 (non-finite or
implausible) or not at all (out of order); a parameter request that raises is refused with the
reason; an error inside a control law gives u = 0 and a report.  controller/status is published
at once on every switch and every change of fault, /diagnostics at once when the state goes
stale.

All algorithms live in :mod:`rwpend_control.supervisor`, :mod:`.laws`, :mod:`.design` (no rclpy).
"""
from __future__ import annotations

import math
import secrets
import struct
import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from std_msgs.msg import Bool

from rwpend_msgs.msg import ControllerStatus, MotorCommand, StateEstimate
from rwpend_msgs.srv import SetMode
from rwpend_ros import wire
from rwpend_ros.claim import format_id
from rwpend_ros.trace import tracer
from rwpend_ros.diagnostics import publish_diagnostic
from rwpend_ros.nodes import RwNode, SlackTimer, local_subscription, say_other_clock
from rwpend_ros.params import ConfigError, ParameterTable, declare_rig
from rwpend_ros.qos import QOS_CONTROL_LATEST, QOS_CONTROL_PUB, QOS_LATCHED, QOS_STATUS
from rwpend_ros.runner import run_node
from rwpend_ros.simtime import sample_time
from rwpend_control.parameters import (DESIGN_DEFAULTS, DESIGN_GROUPS, DESIGNED, MODES, PARAM_FIELDS,
                                       controller_specs, design_group)
from rwpend_control.user_law import LawError, load_law
from rwpend_control.status_codes import FAULT_NONE, FAULT_STALE_STATE, SAFETY_SWITCHES
from rwpend_control.supervisor import STALE_FAULT, Controller, ControllerConfig, Status, gains_from_design
#: Period of the stale-state check (s, steady clock): the controller notices a silent state
#: stream within state_timeout_samples h + this.  The plant's own command timeout zeros the
#: motor within its timeout regardless.
WATCHDOG_PERIOD = 0.005


def _time_msg(t: float) -> Time:
    sec = math.floor(t)
    return Time(sec=int(sec), nanosec=min(int(round((t - sec) * 1e9)), 999_999_999))


class ControllerNode(RwNode):
    def __init__(self, loop_lock=None, hosted: bool = False, plant_here: bool = True, **node_kwargs) -> None:
        """``loop_lock``: the loop's lock when the loop's process hosts this node (rwpend_loop.host),
        else None; ``hosted``: that process runs :attr:`ctrl` every sample and calls
        :meth:`publish_result` -- no ``state`` subscription here; ``plant_here``: the plant is
        a node of that process too (its e-stop comes as a call, and the state cannot stop
        coming inside the loop: no stale-state watchdog); False when the plant is elsewhere
        (rwpend_loop.control: the samples come from the ``encoders`` topic), then the e-stop
        comes on ``estop/state`` and the watchdog runs as in a process of its own. node_kwargs
        go to rclpy Node (context, parameter_overrides, namespace) for tests."""
        self.hosted = bool(hosted)
        watched = not self.hosted or not plant_here
        super().__init__('controller', loop_lock=loop_lock, **node_kwargs)
        self.param_table = ParameterTable(self)
        self.rig = declare_rig(self.param_table)
        self.sample_time = sample_time(self, self.param_table)   # lockstep: ROS time from the samples' stamps
        p = self.param_table.declare(controller_specs(self.rig, QOS_CONTROL_LATEST.depth))
        #: the design parameters the gains were designed from (a group is redesigned when one
        #: of its design parameters changes value)
        self.designs = {n: p[n] for n in DESIGN_DEFAULTS}
        values = self._given_or_designed(p)
        try:
            self.ctrl = Controller(self.rig, ControllerConfig())  # placeholder, replaced below
        except ValueError as exc:  # pragma: no cover - defaults are valid
            raise ConfigError(str(exc)) from exc
        ok, reason, cfg = self.ctrl.check_params(values)
        if not ok:
            raise ConfigError(f'controller parameters: {reason}')
        self.ctrl = Controller(self.rig, cfg, user_law=self._load_user_law(p['law.file'], p['law.params']))
        for r in self.set_parameters([Parameter(n, value=float(values[n])) for n in sorted(DESIGNED)]):
            if not r.successful:
                raise ConfigError(f'designed gains: {r.reason}')
        self.status_every = p['status_every']
        ok, msg = self.ctrl.set_mode(p['mode'])
        if not ok:
            raise ConfigError(msg)

        self.controller_id = self._controller_id(p['controller_id'])
        self.samples = 0
        self.malformed_states = 0    # states whose bytes do not decode (refused, not answered)
        self._last_header = wire.pack_header(0, 0, '')   # of the newest state (frame_id of a stale command)
        self.trace = tracer('controller')   # None unless RWPEND_TRACE is set (profiling)
        self.unanswered = 0          # states refused without a command (out of order)
        self.law_errors = 0          # exceptions inside the control laws (u = 0)
        self.param_errors = 0        # exceptions while validating parameters (refused)
        self.stale_fault = ''        # the fault while the state is stale
        self.other_clock = None      # why the states' stamps are not on this node's clock (checked once)
        self._clock_checked = False
        self._last_fault_code = FAULT_NONE
        self._since_status = 0
        self._syncing = False
        self._pending_params: list[Parameter] = []
        self._create_interfaces(p, watched)
        self.cmd_msg = MotorCommand()
        self.last_status = None
        c = self.ctrl.config
        self.get_logger().info(
            f'mode {self.ctrl.mode}; balance ({c.balance_kpp:.4g}, {c.balance_kdp:.4g}, {c.balance_kpr:.4g}, '
            f'{c.balance_kdr:.4g}); patch ({c.patch_kpp:.4g}, {c.patch_kdp:.4g}, {c.patch_kdr:.4g}); '
            f'swingup c_e={c.swingup_c_e:.4g} c_v={c.swingup_c_v:.4g}; friction {c.friction_compensation}; '
            f'controller id {format_id(self.controller_id)}')

    def _given_or_designed(self, p: dict) -> dict:
        """The controller's parameter values of ``p``, each gain not given designed from the
        design parameters of its group (:attr:`designs`)."""
        values = {n: p[n] for n in PARAM_FIELDS}
        for group, names in DESIGN_GROUPS.items():
            if any(values[n] is None for n in names):
                try:
                    designed = gains_from_design(self.rig, group, self._spec(group, self.designs))
                except (ValueError, TypeError, KeyError, ArithmeticError) as exc:
                    raise ConfigError(f'{group} design: {exc}') from exc
                for n in names:
                    if values[n] is None:
                        values[n] = designed[n]
        return values

    def _create_interfaces(self, p: dict, watched: bool) -> None:
        """The parameter callbacks, publishers, subscriptions, service and timers; ``watched``:
        the e-stop comes on ``estop/state`` and the stale-state watchdog runs."""
        self.add_on_set_parameters_callback(self.on_set_parameters)
        self.add_post_set_parameters_callback(self.on_parameters_set)
        self.pub_cmd = self.create_publisher(MotorCommand, 'command', QOS_CONTROL_PUB)
        self.pub_status = self.create_publisher(ControllerStatus, 'controller/status', QOS_STATUS)
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', QOS_STATUS)
        depth = p['state_queue_depth']
        self.sub_state = None if self.hosted else local_subscription(
            self, StateEstimate, 'state', self.on_state,
            QoSProfile(reliability=QOS_CONTROL_LATEST.reliability, history=QOS_CONTROL_LATEST.history,
                       depth=depth, durability=QOS_CONTROL_LATEST.durability))
        self.create_service(SetMode, '~/set_mode', self.on_set_mode)
        # the plant's e-stop as it is (latched, from the simulator or the driver); in the loop's
        # process the simulator calls on_estop_state itself, before the next sample (one path)
        if watched:
            self.create_subscription(Bool, 'estop/state', self.on_estop_state, QOS_LATCHED)
        # in the loop's slack: after the command of a sample, not while a state waits (19.)
        self.diag_timer = SlackTimer(self, 1.0, self.publish_diagnostics)
        self.create_timer(0.05, self._do_sync)
        # steady clock: fires while sim time stands still too (a stale state in lockstep shows
        # as sim time moving on without states; judged on the node's clock in _check_stale)
        if watched:
            self.create_timer(WATCHDOG_PERIOD, self._check_stale, clock=Clock(clock_type=ClockType.STEADY_TIME))

    # ------------------------------------------------------------ parameters
    @staticmethod
    def _controller_id(value) -> int:
        """The ``controller_id`` parameter, or a random non-zero id for 0."""
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < 2**63:
            raise ConfigError(f'controller_id must be an integer in 0..2^63-1, got {value!r}')
        return value or secrets.randbits(63) | 1

    def _load_user_law(self, source: str, params: str):
        """The law of mode ``law`` from the values of ``law.file`` / ``law.params`` (None when no file)."""
        if not source:
            return None
        try:
            law = load_law(str(source), str(params), self.rig)
        except LawError as exc:
            raise ConfigError(str(exc)) from exc
        self.get_logger().info(f'law: {law.name} of {source}')
        return law

    def _spec(self, group: str, designs: dict) -> dict:
        prefix = f'{group}.design.'
        return {k[len(prefix):]: v for k, v in designs.items() if k.startswith(prefix)}

    def _candidate(self, params) -> tuple[dict, list[str]]:
        """Controller values implied by ``params`` (explicit gains win over redesigned ones)."""
        changes = {p.name: p.value for p in params}
        values = {n: v for n, v in changes.items() if n in PARAM_FIELDS}
        # a design parameter set to the value it has changes nothing (ros2 param load of a dump
        # sets every parameter: the gains it holds, tuned or not, stay as they are)
        redesign = {n: v for n, v in changes.items() if n in DESIGN_DEFAULTS and v != self.designs[n]}
        groups = {design_group(n) for n in redesign}
        designs = {**self.designs, **redesign}
        errors = []
        for group in sorted(groups):
            try:
                designed = gains_from_design(self.rig, group, self._spec(group, designs))
            except (ValueError, TypeError, KeyError, ArithmeticError) as exc:
                errors.append(f'{group} design: {exc}')
                continue
            for n, v in designed.items():
                values.setdefault(n, v)
        return values, errors

    def on_set_parameters(self, params) -> SetParametersResult:
        """Validate only (the node still holds the old values here).  Never raises: whatever a
        request holds, the answer is a reason."""
        if self._syncing:
            return SetParametersResult(successful=True)
        try:
            return self._validate(params)
        except Exception as exc:  # noqa: BLE001 - a malformed request must not kill the node
            self.param_errors += 1
            reason = f'refused: {type(exc).__name__}: {exc}'
            self.get_logger().warn(f'parameter request {[(p.name, p.value) for p in params]!r:.300}: {reason}',
                                   throttle_duration_sec=1.0)
            return SetParametersResult(successful=False, reason=reason)

    def _validate(self, params) -> SetParametersResult:
        reasons = []
        for p in params:
            if p.name.startswith('rig.'):
                reasons.append(f'{p.name} is read-only')
            elif p.name == 'mode':
                ok, why = self._mode_possible(p.value)
                if not ok:
                    reasons.append(why)
        values, errors = self._candidate(params)
        reasons += errors
        if values and not errors:
            ok, why, _ = self.ctrl.check_params(values)
            if not ok:
                reasons.append(why)
        return SetParametersResult(successful=not reasons, reason='; '.join(reasons))

    def _mode_possible(self, mode) -> tuple[bool, str]:
        if not isinstance(mode, str) or mode not in MODES:
            return False, f'mode must be one of {", ".join(MODES)}, got {mode!r}'
        if self.ctrl.estopped and mode != 'off':
            return False, f'mode {mode} refused: the e-stop is raised (clear it first: ./rwpend estop --clear)'
        x = self.ctrl._last_x
        if mode == 'balance' and mode != self.ctrl.mode and x is not None and abs(x) > self.ctrl.config.theta_0:
            return False, (f'balance refused: |theta-pi| = {abs(x):.3g} > theta_0 = '
                           f'{self.ctrl.config.theta_0:g} (use auto to swing up)')
        return True, ''

    def on_parameters_set(self, params) -> None:
        """Apply accepted values."""
        if self._syncing:
            return
        explicit = {p.name for p in params}
        # a value set now wins over one a redesign or a switch scheduled before
        self._pending_params = [p for p in self._pending_params if p.name not in explicit]
        for p in params:
            if p.name == 'status_every':
                self.status_every = int(p.value)
        values, errors = self._candidate(params)
        self.designs.update({p.name: p.value for p in params if p.name in DESIGN_DEFAULTS})
        if values and not errors:
            ok, why = self.ctrl.set_params(values)
            if not ok:  # pragma: no cover - validated in on_set_parameters
                self.get_logger().error(f'parameters not applied: {why}')
            # redesigned gains: show them in the gain parameters too
            sync = [Parameter(n, value=v) for n, v in values.items() if n not in explicit]
            if sync:
                self._schedule_sync(sync)
            self.get_logger().info('parameters: ' + ', '.join(f'{n}={v:.6g}' if isinstance(v, float) else f'{n}={v}'
                                                              for n, v in sorted(values.items())))
        for p in params:
            if p.name == 'mode' and p.value != self.ctrl.mode:
                ok, msg = self.ctrl.set_mode(p.value)
                if not ok:  # state changed between validation and application
                    self.get_logger().warn(msg)
                    self._schedule_sync([Parameter('mode', value=self.ctrl.mode)])

    def _schedule_sync(self, params: list[Parameter]) -> None:
        """Set parameters to reflect the controller, outside the parameter callbacks."""
        self._pending_params.extend(params)

    def _do_sync(self) -> None:
        """Housekeeping timer (20 Hz): a timer that lives as long as the node -- rclpy's
        EventsExecutor failed on a one-shot timer destroyed in its own callback (measured)."""
        params, self._pending_params = self._pending_params, []
        if params:
            self._syncing = True
            try:
                self.set_parameters(params)
            finally:
                self._syncing = False

    # ------------------------------------------------------------ callbacks
    def on_state(self, data: bytes) -> None:
        """One state sample, taken as wire bytes (rwpend_ros.wire: no message object built per
        sample); the command goes out as bytes too, with the state's header (stamp and
        frame_id) copied through, or now if the state's stamp is zero."""
        rx = time.monotonic_ns() if self.trace is not None else 0
        if self.sample_time is not None:
            self.sample_time(data)
        now_t = self.get_clock().now()
        now = now_t.nanoseconds * 1e-9
        try:
            header, seq, theta, theta_dot, wheel_angle, wheel_rate, friction, _, resyncs, _ = \
                wire.unpack_state(data)
        except (struct.error, IndexError) as exc:   # truncated bytes: counted, not answered
            self.malformed_states += 1
            self.get_logger().warn(f'malformed state refused: {exc}', throttle_duration_sec=1.0)
            return
        if rx:
            self.trace('ctl.rx', seq, rx)
        self._last_header = header
        sec, nanosec = wire.header_stamp(header)
        if not self._clock_checked and (sec or nanosec):
            self._check_clock(sec + nanosec * 1e-9, now)
        if sec == 0 and nanosec == 0:
            sec, nanosec = divmod(now_t.nanoseconds, 1_000_000_000)
            header = wire.pack_header(sec, nanosec, wire.header_frame_id(header))
        t = sec + nanosec * 1e-9
        try:
            u, st = self.ctrl.update(t, seq, theta, theta_dot, wheel_angle, wheel_rate, friction, now=now,
                                     resyncs=resyncs)
        except Exception as exc:  # noqa: BLE001 - a fault in a law: zero torque, reported
            self.law_errors += 1
            u, st = 0.0, self.ctrl.internal_error(t, seq, exc)
        if not math.isfinite(u) or abs(u) > self.ctrl.u_max:   # pragma: no cover - saturated above
            u = 0.0
        self.publish_result(header, seq, u, st, sec, nanosec)

    def _check_clock(self, stamp_s: float, now_s: float) -> None:
        """The first stamped state from the topic: on this node's clock? Said once (log,
        /diagnostics ``other_clock``) when not (rwpend_ros.health.other_clock)."""
        self._clock_checked = True
        self.other_clock = say_other_clock(self, stamp_s, now_s)
        if self.other_clock:
            self.publish_diagnostics()

    def publish_result(self, header: bytes, seq: int, u: float, st, sec: int, nanosec: int) -> bytes | None:
        """What the law gave for state ``seq``: ``command`` (with the state's header), the
        status when due or changed, the log lines of switches and faults; returns the
        command's bytes (None: the state was refused unanswered)."""
        self._last_header = header          # (the loop's own states come here, not through on_state)
        if not st.answer:
            self.unanswered += 1
            self.get_logger().warn(st.fault, throttle_duration_sec=1.0)
            return None
        if st.note:
            self.stale_fault = ''
            self.get_logger().info(st.note, throttle_duration_sec=1.0)
        if self.trace is not None:
            self.trace('ctl.pub', seq)
        cmd = wire.pack_command(header, seq, u, self.controller_id)
        self.pub_cmd.publish(cmd)
        self.samples += 1
        self.diag_timer.sample_done()
        self._since_status += 1
        self.last_status = st
        if st.event is not None or st.note or st.fault_code != self._last_fault_code \
                or self._since_status >= self.status_every:
            self._since_status = 0
            self._last_fault_code = st.fault_code
            self.publish_status(st, sec, nanosec)
            if st.note:
                self.publish_diagnostics()
        if st.event is not None:
            ev = st.event
            # one call site per severity: rclpy refuses a severity change at a call site
            if ev.code in SAFETY_SWITCHES:
                self.get_logger().warn(f'safety switch {ev.from_} -> {ev.to}: {ev.reason}')
            elif ev.from_ == ev.to:      # a fresh start of the same law: every stale episode
                self.get_logger().info(f'switch {ev.from_} -> {ev.to}: {ev.reason}',
                                       throttle_duration_sec=1.0)
            else:
                self.get_logger().info(f'switch {ev.from_} -> {ev.to}: {ev.reason}')
            if self.get_parameter('mode').value != self.ctrl.mode:
                self._schedule_sync([Parameter('mode', value=self.ctrl.mode)])
        if st.fault:
            self.get_logger().warn(st.fault, throttle_duration_sec=1.0)
        return cmd

    def _check_stale(self) -> None:
        """Timer: no new state for state_timeout_samples h on the node's clock -> one zero
        command answering the next sample, the fault in controller/status and /diagnostics."""
        now_t = self.get_clock().now()
        st = self.ctrl.check_stale(now_t.nanoseconds * 1e-9)
        if st is None:
            return
        stamp = now_t.to_msg()
        c = self.cmd_msg
        c.header.stamp = stamp
        c.header.frame_id = wire.header_frame_id(self._last_header)
        c.seq = st.seq
        c.u = 0.0
        c.controller_id = self.controller_id
        self.pub_cmd.publish(c)
        self.stale_fault = st.fault
        self.last_status = st
        self._last_fault_code = FAULT_STALE_STATE
        self._since_status = 0
        self.publish_status(st, stamp.sec, stamp.nanosec)
        self.publish_diagnostics()
        self.get_logger().warn(st.fault, throttle_duration_sec=1.0)

    def publish_status(self, st, sec: int, nanosec: int) -> None:
        """controller/status as wire bytes (rwpend_ros.wire: the same bytes for the same status,
        so two lockstep runs record the same bag)."""
        t = _time_msg(st.last_switch)
        self.pub_status.publish(wire.pack_controller_status(
            wire.pack_header(sec, nanosec, ''), st.seq, st.mode, st.law, st.u, st.u_unsaturated,
            st.friction_compensation, st.saturated, (t.sec, t.nanosec), st.switch_count, st.switch_code, st.reason,
            st.fault_code, st.fault))

    def on_estop_state(self, msg: Bool) -> None:
        """The plant's e-stop: raised -> off at once; cleared -> still off until a mode is set."""
        if self.ctrl.estop(bool(msg.data)):
            ev = self.ctrl.events[-1]
            self.get_logger().warn(f'switch {ev.from_} -> {ev.to}: {ev.reason}')
            self._schedule_sync([Parameter('mode', value=self.ctrl.mode)])
            self.publish_status(Status(t=self.ctrl.t, seq=self.ctrl.watchdog.last_seq or 0, mode=self.ctrl.mode,
                                       law=self.ctrl.law, last_switch=self.ctrl.last_switch,
                                       switch_count=self.ctrl.switch_count, reason=self.ctrl.reason,
                                       switch_code=self.ctrl.switch_code),
                                *divmod(self.get_clock().now().nanoseconds, 1_000_000_000))

    def on_set_mode(self, req: SetMode.Request, resp: SetMode.Response) -> SetMode.Response:
        resp.previous_mode = self.ctrl.mode
        ok, msg = self.ctrl.set_mode(req.mode)
        resp.success, resp.message = ok, msg
        if ok:
            self._schedule_sync([Parameter('mode', value=self.ctrl.mode)])
            self.get_logger().info(f'set_mode: {msg}')
        return resp

    def publish_diagnostics(self) -> None:
        st = self.last_status
        ctrl = self.ctrl
        wd = ctrl.watchdog
        if st is None:
            level, message = DiagnosticStatus.STALE, 'no state sample yet'
        elif ctrl.stale:
            level, message = DiagnosticStatus.ERROR, self.stale_fault or f'{STALE_FAULT}: u = 0'
        elif st.fault:
            level, message = DiagnosticStatus.ERROR, st.fault
        elif ctrl.law == 'brake' or ctrl.switch_code in SAFETY_SWITCHES:
            level, message = DiagnosticStatus.WARN, f'{ctrl.mode}/{ctrl.law}: {ctrl.reason}'
        elif ctrl.bad_state_count or wd.out_of_order or wd.episodes:
            level, message = DiagnosticStatus.WARN, (
                f'{ctrl.mode}/{ctrl.law}; refused {ctrl.bad_state_count} bad and {wd.out_of_order} '
                f'out-of-order states; {wd.episodes} stale episodes')
        else:
            level, message = DiagnosticStatus.OK, f'{ctrl.mode}/{ctrl.law}'
        publish_diagnostic(
            self.pub_diag, self.get_clock().now().nanoseconds,
            f'{self.get_namespace().rstrip("/")}/controller', 'rwpend', level, message, {
                'mode': self.ctrl.mode, 'law': self.ctrl.law, 'samples': self.samples,
                'switch_count': self.ctrl.switch_count, 'reason': self.ctrl.reason,
                'bad_states': self.ctrl.bad_state_count,
                'out_of_order_states': wd.out_of_order, 'stale': ctrl.stale,
                'stale_episodes': wd.episodes, 'state_gaps': wd.gaps, 'state_restarts': wd.restarts,
                'last_state_seq': wd.last_seq, 'overspeed_trips': ctrl.overspeed_trips,
                'saturation_trips': ctrl.saturation_trips, 'fall_trips': ctrl.fall_trips,
                'fresh_starts': ctrl.fresh_starts,
                'estimator_resyncs': '' if ctrl.estimator_resyncs is None else ctrl.estimator_resyncs,
                'law_errors': self.law_errors, 'param_errors': self.param_errors,
                'malformed_states': self.malformed_states,
                'friction_compensation': self.ctrl.config.friction_compensation,
                'state_order': self.sub_state.summary() if self.sub_state is not None else 'in the loop',
                'other_clock': self.other_clock or '',
                'controller_id': format_id(self.controller_id),
            })

    def close(self) -> None:
        """Stopping: give the rig up (rwpend_ros.claim) with a last command, u = 0, answering
        the sample after the newest state and flagged ``release``, so that another controller
        may take over at once instead of after the plant's command timeout (not in lockstep)."""
        seq = self.ctrl.watchdog.last_seq
        if seq is None or seq < 0:
            return
        if self.get_parameter('use_sim_time').value:
            # lockstep: the run ends with the simulator, there is no rig to hand over, and a
            # release after the last sample would make the bag depend on the order of the stop
            return
        sec, nanosec = wire.header_stamp(self._last_header)
        header = wire.pack_header(sec, nanosec, wire.header_frame_id(self._last_header))
        try:
            self.pub_cmd.publish(wire.pack_command(header, seq + 1, 0.0, self.controller_id, release=True))
        except Exception:  # noqa: BLE001 - the context may be gone already (the plant's timeout covers it)
            pass


def main(args=None) -> int:
    return run_node(ControllerNode, args=args)


if __name__ == '__main__':
    raise SystemExit(main())
