"""``estimator`` node: encoder counts -> state estimate, every sample.

Subscribes ``encoders`` (EncoderCounts) and ``command`` (MotorCommand: the u used for sample k
is the latest valid command received, saturated to |u| <= u_max); publishes for every encoder
sample ``state`` (StateEstimate, seq and header copied from the encoder sample) and, unless
``publish_joint_states`` is false, ``joint_states`` (sensor_msgs/JointState, joints
``pendulum`` = theta and ``wheel`` = theta_r - theta, the wheel's angle relative to the
pendulum, i.e. the joint coordinate of a base -> pendulum -> wheel chain).
``~/reset`` (std_srvs/Trigger) re-zeros the encoders at the counts of the newest sample.
``/diagnostics`` once a second: estimator, samples, refused samples and commands, gaps, bridged
samples, the longest gap, re-synchronisations and the last one's reason; a log line (throttled)
at each re-synchronisation.  StateEstimate carries ``resyncs`` and ``missed``.

Every setting of :class:`rwpend_estimation.estimators.EstimatorConfig` is a ROS parameter of
the same name, changeable while running: new values are validated in the on-set callback
(refused with the reason) and applied in the post-set callback, where the new estimator
continues from the current estimate without a jump (``switch_estimator``).
Implausible samples, repeated samples and non-finite commands are counted and ignored; gaps
are bridged or re-synchronised (:mod:`rwpend_estimation.gaps`).

All algorithms live in :mod:`rwpend_estimation.estimators`, :mod:`.gaps` and, for the
sample/command alignment, :mod:`.alignment` (pure, no rclpy).
"""
from __future__ import annotations

import struct
from dataclasses import asdict, fields

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from rwpend_msgs.msg import EncoderCounts, MotorCommand, StateEstimate
from rwpend_ros.sched import thread_priority_spec
from rwpend_ros import wire
from rwpend_ros.trace import tracer
from rwpend_ros.diagnostics import publish_diagnostic
from rwpend_ros.nodes import RwNode, SlackTimer, local_subscription, say_other_clock
from rwpend_ros.params import ConfigError, ParameterTable, declare_rig
from rwpend_ros.paramspec import ParamSpec
from rwpend_ros.qos import QOS_CONTROL, QOS_CONTROL_PUB, QOS_STATUS
from rwpend_ros.runner import run_node
from rwpend_ros.simtime import sample_time
from rwpend_estimation.alignment import CommandAlignment
from rwpend_estimation.estimators import (ESTIMATORS, FRICTION_SOURCES, LIMITS, MAX_BRIDGE,
                                          DuplicateSampleError, EstimatorConfig, make_estimator,
                                          switch_estimator)

DESCRIPTIONS = {
    'estimator': 'the estimator (Chapters 3 and 7)',
    'T': 'time constant of the filtered difference (3.3), s (0 = plain difference)',
    'omega0': 'bandwidth of the wheel observers (3.6)/(3.10) and the joint observer (7.3), rad/s',
    'zeta': 'damping of the wheel observers and the joint observer',
    'alpha': 'friction pole alpha*omega0 of (3.10) and (7.3)',
    'pendulum_omega0': 'bandwidth of the nonlinear pendulum observer (7.1), rad/s',
    'pendulum_zeta': 'damping of the nonlinear pendulum observer (7.1)',
    'friction_source': 'friction estimate in StateEstimate: the observer\'s, the model (3.17), none',
    'theta_offset': 'calibration added to theta (rad), pi if started upright',
    'max_rate': 'samples implying a faster encoder motion (rad/s) over the seq gap are refused',
    'max_bridge': 'most missing samples bridged (observers stepped through them); longer gaps '
                  're-synchronise on the counts',
    'command_timeout_samples': "the plant's command timeout (samples): over a bridged gap the last "
                               'command is held this long, then 0',
}
CONFIG_NAMES = tuple(f.name for f in fields(EstimatorConfig))
_CHOICES = {'estimator': ESTIMATORS, 'friction_source': FRICTION_SOURCES}


def _config_spec(name: str, default) -> ParamSpec:
    """The parameter of one EstimatorConfig setting: bounds from estimators.LIMITS."""
    if name in LIMITS:
        lo, lo_incl, hi = LIMITS[name]
        return ParamSpec(name, default, DESCRIPTIONS[name], low=lo, low_open=not lo_incl, high=hi,
                         constraints='stable observers at h' if name in ('omega0', 'pendulum_omega0') else '')
    if name in ('max_bridge', 'command_timeout_samples'):
        return ParamSpec(name, default, DESCRIPTIONS[name], low=0, high=MAX_BRIDGE)
    return ParamSpec(name, default, DESCRIPTIONS[name], choices=_CHOICES.get(name, ()))


#: The estimator's parameters: every setting of EstimatorConfig and publish_joint_states
#: (changeable while running), diagnostics_period (set at start).
PARAMS = [_config_spec(name, default) for name, default in asdict(EstimatorConfig()).items()] + [
    ParamSpec('publish_joint_states', True, 'publish sensor_msgs/JointState on joint_states'),
    ParamSpec('diagnostics_period', 1.0, 'seconds between /diagnostics messages', low=0.0,
              low_open=True, read_only=True),
    thread_priority_spec(),
]


#: ``~/reset`` is refused until this long after the last non-zero command (s)
RESET_QUIET_S = 0.5


class EstimatorNode(RwNode):
    def __init__(self, loop_lock=None, hosted: bool = False, **node_kwargs) -> None:
        """``loop_lock``: the loop's lock when the loop's process hosts this node
        (rwpend_loop.host), else None; ``hosted``: that process steps the estimator
        (:attr:`stage`) and calls :meth:`publish_estimate` -- no subscription of ``encoders``
        or ``command`` here; node_kwargs go to rclpy Node (e.g. context, parameter_overrides,
        namespace) for tests."""
        self.hosted = bool(hosted)
        #: the loop's estimator stage (rwpend_loop.loop.EstimatorStage) when hosted: it steps
        #: :attr:`est`, and is given the new one when the settings change
        self.stage = None
        super().__init__('estimator', loop_lock=loop_lock, **node_kwargs)
        self.param_table = ParameterTable(self)
        self.rig = declare_rig(self.param_table)
        self.sample_time = sample_time(self, self.param_table)   # lockstep: ROS time from the samples' stamps
        p = self.param_table.declare(PARAMS)
        try:
            self.config = EstimatorConfig.from_values({n: p[n] for n in CONFIG_NAMES}, rig=self.rig)
        except ValueError as exc:
            raise ConfigError(f'estimator parameters: {exc}') from exc
        self.publish_joint_states = p['publish_joint_states']
        period = p['diagnostics_period']
        self.est = make_estimator(None, self.rig, self.config)
        self.align: CommandAlignment[Sample] = CommandAlignment(self.rig.u_max)
        # counters (the estimator's own: self.est.gap_stats)
        self.samples = 0
        self.malformed_samples = 0
        self.refused_commands = 0
        self.last_error = ''
        self.switches = 0
        self._resyncs_seen = 0
        self.last_drive_seq: int | None = None   # newest sample answered by a non-zero command
        self.refused_resets = 0
        self.other_clock = None      # why the samples' stamps are not on this node's clock (checked once)
        self._clock_checked = False

        self.add_on_set_parameters_callback(self.on_set_parameters)
        self.add_post_set_parameters_callback(self.on_parameters_set)
        self.pub_state = self.create_publisher(StateEstimate, 'state', QOS_CONTROL_PUB)
        self.pub_joints = self.create_publisher(JointState, 'joint_states', QOS_CONTROL_PUB)
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', QOS_STATUS)
        # the per-sample path takes and publishes wire bytes (rwpend_ros.wire): no message
        # objects built or converted field by field (measured: PERFORMANCE.md). Each
        # subscription's order gate drops duplicates and older messages (rwpend_ros.order)
        self.sub_enc = self.sub_cmd = None
        if not self.hosted:
            self.sub_enc = local_subscription(self, EncoderCounts, 'encoders', self.on_encoders_raw, QOS_CONTROL)
            self.sub_cmd = local_subscription(self, MotorCommand, 'command', self.on_command_raw, QOS_CONTROL)
            self.command_topic = self.sub_cmd.topic_name
        self.create_service(Trigger, '~/reset', self.on_reset)
        # in the loop's slack: after the state of a sample, not while a sample waits (19.)
        self.diag_timer = SlackTimer(self, float(period), self.publish_diagnostics)

        self.trace = tracer('estimator')      # None unless RWPEND_TRACE is set (profiling)
        self.state_packer = wire.StatePacker(self.config.estimator)
        self.joint_packer = wire.JointStatePacker(('pendulum', 'wheel'))
        self.get_logger().info(f'estimator {self.config.estimator}, h = {self.rig.sample_period * 1e3:g} ms, '
                               f'friction source {self.config.friction_source}')

    # ------------------------------------------------------------ parameters
    def _candidate(self, params) -> EstimatorConfig:
        changes = {p.name: p.value for p in params if p.name in CONFIG_NAMES}
        return EstimatorConfig.from_values(changes, base=self.config, rig=self.rig)

    def on_set_parameters(self, params) -> SetParametersResult:
        """Validate only (the node still holds the old values here)."""
        reasons = []
        for p in params:
            if p.name == 'publish_joint_states' and not isinstance(p.value, bool):
                reasons.append(f'publish_joint_states must be a bool, got {p.value!r}')
        try:
            self._candidate(params)
        except ValueError as exc:
            reasons.append(str(exc))
        except Exception as exc:  # noqa: BLE001 - a malformed request must not kill the node
            reasons.append(f'refused: {type(exc).__name__}: {exc}')
        return SetParametersResult(successful=not reasons, reason='; '.join(reasons))

    def on_parameters_set(self, params) -> None:
        """Apply accepted values: switch estimator without a jump."""
        for p in params:
            if p.name == 'publish_joint_states':
                self.publish_joint_states = bool(p.value)
        if not any(p.name in CONFIG_NAMES for p in params):
            return
        config = self._candidate(params)
        if config == self.config:
            return
        self.est = switch_estimator(self.est, config)
        if self.stage is not None:
            self.stage.est = self.est
        self.config = config
        self.state_packer.set_estimator(config.estimator)
        self.switches += 1
        self.get_logger().info(f'estimator settings: {config}')

    # ------------------------------------------------------------ callbacks
    def on_command(self, msg: MotorCommand) -> None:
        self.command(int(msg.seq), msg.u)

    def on_command_raw(self, data: bytes) -> None:
        try:
            seq, u = wire.unpack_command(data)
        except (struct.error, IndexError) as exc:
            self.refused_commands += 1
            self.last_error = f'malformed command: {exc}'
            return
        self.command(seq, u)

    def note_command(self, seq: int, u: float) -> None:
        """A command that answered sample ``seq``: a non-zero one means the loop drives the
        rig (``~/reset`` is refused for :data:`RESET_QUIET_S` after it)."""
        if u != 0.0 and (self.last_drive_seq is None or seq > self.last_drive_seq):
            self.last_drive_seq = seq

    def command(self, seq: int, u: float) -> None:
        self.note_command(seq, u)
        try:
            released = self.align.command(seq, u)
        except ValueError as exc:
            self.refused_commands += 1
            self.last_error = str(exc)
            return
        if released is not None:
            self.process(*released)

    def on_encoders(self, msg: EncoderCounts) -> None:
        st = msg.header.stamp
        header = wire.pack_header(st.sec, st.nanosec, msg.header.frame_id)
        if not self._clock_checked:
            self._check_clock(header)
        self.sample(Sample(header, int(msg.seq), msg.pendulum_counts, msg.motor_counts))

    def on_encoders_raw(self, data: bytes) -> None:
        if self.sample_time is not None:
            self.sample_time(data)
        try:
            msg = Sample(*wire.unpack_encoders(data))
        except (struct.error, IndexError) as exc:   # truncated bytes: counted, nothing else changes
            self.malformed_samples += 1
            self.last_error = f'malformed encoder sample: {exc}'
            return
        if self.trace is not None:
            self.trace('est.rx', msg.seq)
        if not self._clock_checked:
            self._check_clock(msg.header)
        self.sample(msg)

    def _check_clock(self, header: bytes) -> None:
        """The first stamped sample from the topic: on this node's clock? Said once (log,
        /diagnostics ``other_clock``) when not (rwpend_ros.health.other_clock): the estimator's
        /diagnostics would be stamped on another clock than its samples."""
        sec, nanosec = wire.header_stamp(header)
        if not (sec or nanosec):
            return
        self._clock_checked = True
        self.other_clock = say_other_clock(self, sec + nanosec * 1e-9, self.get_clock().now().nanoseconds * 1e-9)

    def sample(self, msg: 'Sample') -> None:
        """Sample k is estimated with the command that answered sample k-1 (held over
        [t_{k-1}, t_k), the u of (3.5)/(7.1)); it may wait for it (rwpend_estimation.alignment)."""
        for seq, s in self.align.sample(msg.seq, msg, self._controller_present):
            self.process(seq, s)

    def _controller_present(self) -> bool:
        return self.count_publishers(self.command_topic) > 0

    def process(self, seq: int, msg: 'Sample') -> None:
        try:
            e = self.est.step(msg.pendulum_counts, msg.motor_counts, self.align.input_for(seq), seq)
        except DuplicateSampleError:
            return                                  # counted in gap_stats
        except ValueError as exc:
            self.last_error = f'seq {seq}: {exc}'
            self.get_logger().warn(self.last_error, throttle_duration_sec=1.0)
            return
        self.publish_estimate(msg.header, seq, e)

    def publish_estimate(self, header: bytes, seq: int, e) -> bytes:
        """The estimate of sample ``seq``: ``state`` and ``joint_states`` (with the sample's
        header), the re-synchronisation log line; returns the state's bytes."""
        self.samples += 1
        if e.resyncs != self._resyncs_seen:
            self._resyncs_seen = e.resyncs
            gs = self.est.gap_stats
            self.get_logger().warn(f'seq {seq}: re-synchronised on the counts ({gs.last_resync}); '
                                   f'{gs.resyncs} re-synchronisations so far', throttle_duration_sec=1.0)
        if self.trace is not None:
            self.trace('est.pub', seq)
        state = self.state_packer.pack(header, seq, e.theta, e.theta_dot, e.wheel_angle, e.wheel_rate,
                                       e.friction, e.energy, e.resyncs, e.missed)
        self.pub_state.publish(state)
        if self.publish_joint_states:
            self.joints = self.joint_packer.pack(
                header, e.theta, e.wheel_angle - e.theta, e.theta_dot, e.wheel_rate - e.theta_dot)
            self.pub_joints.publish(self.joints)
        else:
            self.joints = None
        self.diag_timer.sample_done()
        return state

    def on_reset(self, req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        """Re-zero the encoders at the newest sample -- refused while the loop drives the rig
        (a non-zero command within :data:`RESET_QUIET_S`): zeroing at, say, the upright pose
        makes theta jump by pi, and the controller would call it a fall."""
        n = self.est.newest_sample
        quiet = max(1, round(RESET_QUIET_S / self.rig.sample_period))
        if n is not None and n[0] is not None and self.last_drive_seq is not None \
                and n[0] - self.last_drive_seq < quiet:
            self.refused_resets += 1
            resp.success = False
            resp.message = (f'reset refused: the loop is driving the rig (a non-zero command answered seq '
                            f'{self.last_drive_seq}, {(n[0] - self.last_drive_seq) * self.rig.sample_period * 1e3:.0f} ms '
                            f'ago); set the controller off (./rwpend mode off), let the pendulum hang '
                            f'at rest, then reset')
            self.get_logger().warn(resp.message)
            return resp
        self.est.reset()
        resp.success = True
        n = self.est.newest_sample
        resp.message = (f'encoders re-zeroed at counts {n[1:]} of seq {n[0]}' if n is not None
                        else 'encoders will be zeroed at the first sample')
        self.get_logger().info(resp.message)
        return resp

    def publish_diagnostics(self) -> None:
        gs = self.est.gap_stats
        level = DiagnosticStatus.OK
        message = f'{self.config.estimator}: ok'
        if gs.resyncs:
            message = f'{self.config.estimator}: {gs.resyncs} re-synchronisations, last: {gs.last_resync}'
        if gs.refused or self.malformed_samples or self.refused_commands:
            level = DiagnosticStatus.WARN
            message = f'{self.config.estimator}: {self.last_error}'
        if self.samples == 0:
            level, message = DiagnosticStatus.STALE, 'no encoder sample yet'
        publish_diagnostic(
            self.pub_diag, self.get_clock().now().nanoseconds,
            f'{self.get_namespace().rstrip("/")}/estimator', 'rwpend', level, message, {
                'estimator': self.config.estimator,
                'friction_source': self.config.friction_source,
                'samples': self.samples,
                'refused_samples': gs.refused,
                'duplicate_samples': gs.duplicates,
                'malformed_samples': self.malformed_samples,
                'refused_commands': self.refused_commands,
                'seq_gaps': gs.gaps,
                'missed_samples': gs.missed,
                'bridged_samples': gs.bridged,
                'longest_gap': gs.longest_gap,
                'resyncs': gs.resyncs,
                'last_resync': gs.last_resync,
                'last_resync_seq': '' if gs.last_resync_seq is None else gs.last_resync_seq,
                'deferred_samples': self.align.deferred,
                'plant_restarts': self.align.restarts,
                'switches': self.switches,
                'refused_resets': self.refused_resets,
                'other_clock': self.other_clock or '',
                'encoders_order': self.sub_enc.summary() if self.sub_enc is not None else 'in the loop',
                'command_order': self.sub_cmd.summary() if self.sub_cmd is not None else 'in the loop',
            })


class Sample:
    """One encoder sample: the header as its wire bytes (copied into state and joint_states)."""

    __slots__ = ('header', 'seq', 'pendulum_counts', 'motor_counts')

    def __init__(self, header: bytes, seq: int, pendulum_counts: int, motor_counts: int) -> None:
        self.header, self.seq = header, seq
        self.pendulum_counts, self.motor_counts = pendulum_counts, motor_counts


def main(args=None) -> int:
    return run_node(EstimatorNode, args=args)


if __name__ == '__main__':
    raise SystemExit(main())
