"""Lockstep time for the loop's nodes: ROS time taken from the samples' own stamps
(``time_from_samples``) instead of ``/clock``."""
from __future__ import annotations

import struct

from rclpy.clock import ClockType
from rclpy.time import Time

from rwpend_ros import wire
from rwpend_ros.params import ConfigError
from rwpend_ros.paramspec import ParamSpec

TIME_FROM_SAMPLES_DOC = (
    'lockstep: with use_sim_time, the node\'s ROS time is the stamp of the newest sample it '
    'took (the simulator stamps sample k with its sim time k h, the /clock it publishes next) '
    'instead of /clock, which it then does not subscribe to: one message less per sample '
    '(./rwpend up --lockstep sets it)')


class SampleTime:
    """A node's ROS time from the stamps of the samples it takes (``time_from_samples``).

    In lockstep the simulator publishes sample k stamped with its sim time t_k, then ``/clock``
    = t_k. A node of the loop can take t_k from the sample itself: rclpy's ``/clock``
    subscription (a DDS message, a Python message object and a callback per sample, in every
    node, all competing with the loop for the CPU) is then left out. Measured in lockstep,
    separate processes: 2.5-2.9x -> 3.9-4.4x real time, CPU 0.66-0.77 -> 0.34-0.38 s per
    simulated s (PERFORMANCE.md, "What each mechanism buys"). The time only moves forward; timers on
    the ROS clock fire as with ``/clock`` (the same rclpy override). What ``/clock`` gives and this
    does not: time moving while no sample comes (a controller's stale-state watchdog cannot see
    the estimator stop -- in lockstep the simulator's ``lockstep_timeout`` zeroes the motor
    and counts it instead)."""

    def __init__(self, node) -> None:
        ts = getattr(node, '_time_source', None)
        if ts is None or not hasattr(ts, '_associated_clocks') or not hasattr(ts, '_clock_sub'):
            raise ConfigError('time_from_samples: this rclpy has no TimeSource internals to feed '
                              '(use /clock: time_from_samples false)')
        self._ts = ts
        self._node = node
        self.last_ns = -1
        self._drop_clock_subscription()

    def _drop_clock_subscription(self) -> None:
        sub, self._ts._clock_sub = self._ts._clock_sub, None
        if sub is not None:
            self._node.destroy_subscription(sub)

    def __call__(self, data: bytes) -> None:
        """Advance the node's ROS time to the stamp of ``data`` (wire bytes of a message that
        starts with a Header); an older or malformed stamp changes nothing."""
        try:
            ns = wire.message_stamp_ns(data)
        except struct.error:
            return
        if ns > self.last_ns:
            self.set_time(ns, Time(nanoseconds=ns, clock_type=ClockType.ROS_TIME))

    def set_time(self, ns: int, t: Time) -> None:
        """Advance to ``t`` (= ``ns``, a ROS_TIME Time; the loop's process makes one for all its
        nodes); an older time changes nothing."""
        if ns <= self.last_ns:
            return
        self.last_ns = ns
        if self._ts._clock_sub is not None:      # use_sim_time was set again at run time
            self._drop_clock_subscription()
        self._ts._last_time_set = t
        for clock in self._ts._associated_clocks:
            clock.set_ros_time_override(t)


def sample_time(node, table) -> SampleTime | None:
    """Declare ``time_from_samples`` (read-only bool, default false) on ``node`` through its
    :class:`rwpend_ros.params.ParameterTable`; a :class:`SampleTime` when it is true, None
    otherwise. ConfigError when it is true without ``use_sim_time``, or not a bool."""
    value = table.declare([ParamSpec('time_from_samples', False, TIME_FROM_SAMPLES_DOC,
                                     read_only=True)])['time_from_samples']
    if not value:
        return None
    if node.get_parameter('use_sim_time').value is not True:
        raise ConfigError('time_from_samples needs use_sim_time:=true (it replaces /clock as the '
                          'source of sim time)')
    return SampleTime(node)
