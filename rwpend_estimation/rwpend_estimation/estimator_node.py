"""``estimator`` node: encoder counts -> state estimate, every sample.

Subscribes ``encoders`` (EncoderCounts) and ``command`` (MotorCommand: the u used for sample k
is the latest valid command received, saturated to |u| <= u_max); publishes for every encoder
sample ``state`` (StateEstimate, seq and header copied from the encoder sample) and, unless
``publish_joint_states`` is false, ``joint_states`` (sensor_msgs/JointState, joints
``pendulum`` = theta and ``wheel`` = theta_r - theta, the wheel's angle relative to the
pendulum, i.e. the joint coordinate of a base -> pendulum -> wheel chain).
``~/reset`` (std_srvs/Trigger) re-zeros the encoders at the current counts.
``/diagnostics`` once a second: estimator, samples, refused samples and commands, seq gaps.

Every setting of :class:`rwpend_estimation.estimators.EstimatorConfig` is a ROS parameter of
the same name, changeable while running: new values are validated in the on-set callback
(refused with the reason) and applied in the post-set callback, where the new estimator
continues from the current estimate without a jump (``switch_estimator``).
Invalid samples (implausible jumps) and non-finite commands are counted and ignored.

All algorithms live in :mod:`rwpend_estimation.estimators` (pure, no rclpy).
"""
from __future__ import annotations

import math
import struct
from dataclasses import asdict, fields

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from sensor_msgs.msg import JointState
from std_srvs.srv import Trigger

from rwpend_msgs.msg import EncoderCounts, MotorCommand, StateEstimate
from rwpend_ros import wire
from rwpend_ros.trace import tracer
from rwpend_ros.common import (QOS_CONTROL, QOS_CONTROL_PUB, QOS_STATUS, ConfigError, LocalPublisher, RwNode,
                               SlackTimer, declare_rig, fast_path_values, local_subscription, publish_diagnostic,
                               run_node, sample_time)
from rwpend_estimation.estimators import (ESTIMATORS, FRICTION_SOURCES, EstimatorConfig,
                                          make_estimator, switch_estimator)

DESCRIPTIONS = {
    'estimator': 'estimator: ' + ', '.join(ESTIMATORS),
    'T': 'time constant of the filtered difference (3.3), s',
    'omega0': 'bandwidth of the wheel observers (3.6)/(3.10) and the joint observer (7.3), rad/s',
    'zeta': 'damping of the wheel observers and the joint observer',
    'alpha': 'friction pole alpha*omega0 of (3.10) and (7.3)',
    'pendulum_omega0': 'bandwidth of the nonlinear pendulum observer (7.1), rad/s',
    'pendulum_zeta': 'damping of the nonlinear pendulum observer (7.1)',
    'friction_source': 'friction estimate: ' + ', '.join(FRICTION_SOURCES),
    'theta_offset': 'calibration added to theta (rad), pi if started upright',
    'max_rate': 'samples implying a faster encoder motion (rad/s) are refused',
}
CONFIG_NAMES = tuple(f.name for f in fields(EstimatorConfig))
EXTRA_PARAMS = {
    'publish_joint_states': (True, 'publish sensor_msgs/JointState on joint_states'),
}
READ_ONLY_PARAMS = {
    'diagnostics_period': (1.0, 'seconds between /diagnostics messages'),
}


class EstimatorNode(RwNode):
    def __init__(self, **node_kwargs) -> None:
        """node_kwargs go to rclpy Node (e.g. context, parameter_overrides, namespace) for tests."""
        super().__init__('estimator', **node_kwargs)
        self.rig = declare_rig(self)
        self.sample_time = sample_time(self)   # lockstep: ROS time from the samples' stamps
        defaults = asdict(EstimatorConfig())
        for name in CONFIG_NAMES:
            self.declare_parameter(name, defaults[name], ParameterDescriptor(
                description=DESCRIPTIONS.get(name, name), dynamic_typing=True))
        for name, (default, descr) in EXTRA_PARAMS.items():
            self.declare_parameter(name, default, ParameterDescriptor(description=descr,
                                                                      dynamic_typing=True))
        for name, (default, descr) in READ_ONLY_PARAMS.items():
            self.declare_parameter(name, default, ParameterDescriptor(description=descr, read_only=True,
                                                                      dynamic_typing=True))
        values = {name: self.get_parameter(name).value for name in CONFIG_NAMES}
        try:
            self.config = EstimatorConfig.from_values(values, rig=self.rig)
        except ValueError as exc:
            raise ConfigError(f'estimator parameters: {exc}') from exc
        pjs = self.get_parameter('publish_joint_states').value
        if not isinstance(pjs, bool):
            raise ConfigError(f'publish_joint_states must be a bool, got {pjs!r}')
        self.publish_joint_states = pjs
        period = self.get_parameter('diagnostics_period').value
        if isinstance(period, bool) or not isinstance(period, (int, float)) or not (
                math.isfinite(period) and period > 0):
            raise ConfigError(f'diagnostics_period must be a number > 0, got {period!r}')
        self.est = make_estimator(None, self.rig, self.config)
        self.u = 0.0             # latest command received (clamped), for diagnostics
        self.u_seq = -1          # seq answered by the latest command
        self.commands: dict[int, float] = {}   # recent commands by the seq they answer
        self.pending: Sample | None = None
        self.deferred = 0        # samples that waited for their command
        self.u_max = self.rig.u_max
        # counters
        self.samples = 0
        self.refused_samples = 0
        self.refused_commands = 0
        self.seq_gaps = 0
        self.last_seq: int | None = None
        self.last_error = ''
        self.switches = 0

        self.add_on_set_parameters_callback(self.on_set_parameters)
        self.add_post_set_parameters_callback(self.on_parameters_set)
        # state reaches a controller in this process directly (composed mode, rwpend_ros.intra)
        self.pub_state = LocalPublisher(self, StateEstimate, 'state', QOS_CONTROL_PUB)
        self.pub_joints = LocalPublisher(self, JointState, 'joint_states', QOS_CONTROL_PUB)   # recorder: fast path
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', QOS_STATUS)
        # the per-sample path takes and publishes wire bytes (rwpend_ros.wire): no message
        # objects built or converted field by field (measured: PERFORMANCE.md)
        # also straight from a plant / controller in another process of this host
        # (rwpend_ros.hostbus). A command of a controller of this process comes through the
        # in-process bus: published while this node publishes the state it answers, it is
        # delivered right after that callback returns (rwpend_ros.intra: deferred), with no DDS
        # copy. Encoders: from the sample loop of a simulator of this process (real time; in
        # lockstep the simulator writes them to DDS, rwpend_sim.sim_node)
        local_subscription(self, EncoderCounts, 'encoders', self.on_encoders_raw, QOS_CONTROL)
        self.command_topic = local_subscription(self, MotorCommand, 'command', self.on_command_raw,
                                                QOS_CONTROL).topic_name
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

    def command(self, seq: int, u: float) -> None:
        if not math.isfinite(u):
            self.refused_commands += 1
            self.last_error = f'non-finite command u={u!r} ignored'
            return
        um = self.u_max
        self.u = um if u > um else (-um if u < -um else u)
        self.commands[seq] = self.u
        if len(self.commands) > 64:
            del self.commands[next(iter(self.commands))]
        self.u_seq = max(self.u_seq, seq)
        p = self.pending
        if p is not None and self.u_seq >= p.seq - 1:
            self.pending = None
            self.process(p)

    def on_encoders(self, msg: EncoderCounts) -> None:
        st = msg.header.stamp
        self.sample(Sample(wire.pack_header(st.sec, st.nanosec, msg.header.frame_id), int(msg.seq),
                           msg.pendulum_counts, msg.motor_counts))

    def on_encoders_raw(self, data: bytes) -> None:
        if self.sample_time is not None:
            self.sample_time(data)
        try:
            msg = Sample(*wire.unpack_encoders(data))
        except (struct.error, IndexError) as exc:   # truncated bytes: counted, nothing else changes
            self.refused_samples += 1
            self.last_error = f'malformed encoder sample: {exc}'
            return
        if self.trace is not None:
            self.trace('est.rx', msg.seq)
        self.sample(msg)

    def sample(self, msg: 'Sample') -> None:
        """Sample k is estimated with the command that answered sample k-1 (held over
        [t_{k-1}, t_k), the u of (3.5)/(7.1)). The two arrive on different topics from different
        processes, in either order; while the controller is answering (its last command is at
        most 3 samples old) sample k waits for command k-1 -- until that command or sample k+1
        arrives, whichever is first. So a lockstep run gives the same estimates every time."""
        p = self.pending
        if p is not None:
            self.pending = None
            self.process(p)
        if self.u_seq < msg.seq - 1 and self.u_seq >= msg.seq - 4 and (
                self.u_seq >= 0 or self.count_publishers(self.command_topic) > 0):
            # no command yet (u_seq -1: start, plant restarted) counts as answered at seq -1
            # when a controller publishes: samples 1-3 then wait for the first commands too (in
            # a composed lockstep run sample 1 can come before command 0, rwpend_ros.intra)
            self.pending = msg
            self.deferred += 1
            return
        self.process(msg)

    def command_for(self, k: int) -> float:
        """The u held over [t_{k-1}, t_k): the command answering sample k-1, else the newest one
        answering an earlier sample (the amplifier holds it), else 0. Chosen by seq, not by
        arrival order, so a replayed stream gives the live estimates whatever the interleaving
        of the two topics."""
        u = self.commands.get(k - 1)
        if u is not None:
            return u
        older = [s for s in self.commands if s < k]
        return self.commands[max(older)] if older else 0.0

    def process(self, msg: 'Sample') -> None:
        if self.last_seq is not None and msg.seq < self.last_seq:
            # the plant restarted its sample counter (driver reconnect, simulator restart)
            self.commands.clear()
            self.u_seq = -1
        try:
            e = self.est.step(msg.pendulum_counts, msg.motor_counts, self.command_for(int(msg.seq)))
        except ValueError as exc:
            self.refused_samples += 1
            self.last_error = f'seq {msg.seq}: {exc}'
            self.get_logger().warn(self.last_error, throttle_duration_sec=1.0)
            return
        self.samples += 1
        if self.last_seq is not None and msg.seq != self.last_seq + 1:
            self.seq_gaps += 1
        self.last_seq = msg.seq
        if self.trace is not None:
            self.trace('est.pub', msg.seq)
        self.pub_state.publish(self.state_packer.pack(
            msg.header, msg.seq, e.theta, e.theta_dot, e.wheel_angle, e.wheel_rate, e.friction, e.energy))
        if self.publish_joint_states:
            self.pub_joints.publish(self.joint_packer.pack(
                msg.header, e.theta, e.wheel_angle - e.theta, e.theta_dot, e.wheel_rate - e.theta_dot))
        self.diag_timer.sample_done()

    def on_reset(self, req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        self.est.reset()
        resp.success = True
        resp.message = (f'encoders re-zeroed at counts {self.est.raw_counts}' if self.est.raw_counts
                        else 'encoders will be zeroed at the first sample')
        self.get_logger().info(resp.message)
        return resp

    def publish_diagnostics(self) -> None:
        level = DiagnosticStatus.OK
        message = f'{self.config.estimator}: ok'
        if self.refused_samples or self.refused_commands:
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
                'refused_samples': self.refused_samples,
                'refused_commands': self.refused_commands,
                'seq_gaps': self.seq_gaps,
                'deferred_samples': self.deferred,
                'switches': self.switches,
                **fast_path_values(self),
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
