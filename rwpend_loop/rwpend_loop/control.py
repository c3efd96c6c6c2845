"""The loop's process without the plant: the ``estimator`` and ``controller`` nodes around one
loop, fed by the ``encoders`` topic.

    python -m rwpend_loop.host estimator controller --ros-args -r __ns:=/rwpend --params-file ...

The plant (the simulator or the driver) runs in another process -- on the rig's PC when a stack
is split across hosts (``./rwpend up --only``, ``--composed control``). Each ``encoders`` message
is one :meth:`rwpend_loop.loop.Loop.step`, in the executor's thread, holding the loop's lock:
the sample -> the estimator -> the controller -> the command published on ``command`` (the
plant takes it through its own gate: the claim, the freshness rule, the e-stop) -> then, for
observers, ``controller/status``, ``state`` and ``joint_states``. No message between the
estimator and the controller.

The u of sample k (the command held over [t_k-1, t_k), the u of (3.5)/(7.1)) is the command this
process sent for sample k-1, else the newest one before it (the plant holds it), else 0:
:class:`rwpend_estimation.alignment.CommandAlignment`, as a separate estimator reads the
``command`` topic. The e-stop comes on ``estop/state`` and the controller's stale-state
watchdog runs (the samples can stop coming), as in a process of its own.
"""
from __future__ import annotations

import struct

from rwpend_ros import wire
from rwpend_sim.sim_core import Reading

#: seconds between two /diagnostics of the controller (the estimator: its diagnostics_period);
#: on the steady clock: the samples may stop
DIAGNOSTICS_PERIOD = 1.0


class TopicReading:
    """The ``encoders`` topic as the loop's hardware: :meth:`read` gives the sample just taken
    (:meth:`set`), with the command the plant holds over the interval before it, from
    ``align`` (the commands this process sent)."""

    def __init__(self, align) -> None:
        self.align = align
        self.reading: Reading | None = None

    def set(self, seq: int, pc: int, mc: int) -> None:
        self.reading = Reading(seq, pc, mc, self.align.input_for(seq))

    def read(self) -> Reading:
        return self.reading


class TopicGate:
    """The plant's gate is in the plant's process; here every command the controller gives is
    written (published on ``command``), and the plant integrates in its own time."""

    def offer(self, source: int, seq: int, u: float, release: bool = False) -> bool:
        return True

    def interval(self, late: bool) -> float:
        return 0.0

    def take_event(self) -> None:
        return None


class ControlHost:
    """The estimator and the controller of this process and the loop that runs through them on
    each ``encoders`` message (module doc)."""

    def __init__(self, names: list[str]) -> None:
        from rclpy.clock import Clock, ClockType

        from rwpend_loop.host import LoopLock, build_loop_nodes
        from rwpend_loop.loop import ControllerStage, Loop
        from rwpend_msgs.msg import EncoderCounts
        from rwpend_ros.nodes import local_subscription
        from rwpend_ros.params import refuse_undeclared
        from rwpend_ros.qos import QOS_CONTROL
        self.lock = LoopLock()
        self.est, self.ctrl = build_loop_nodes(names, self.lock, plant_here=False)
        self.nodes = [self.est, self.ctrl]
        refuse_undeclared(self.nodes)       # a misspelt name is an error, not ignored
        self.hw = TopicReading(self.est.align)
        self.loop = Loop(self.hw, TopicGate(), self.est.stage,
                         ControllerStage(self.ctrl.ctrl, self.ctrl.controller_id), self.est.rig.sample_period)
        #: lockstep: the nodes' ROS time from the samples' stamps (rwpend_ros.simtime)
        self.sample_clocks = [c for c in (self.est.sample_time, self.ctrl.sample_time) if c is not None]
        lock = self.lock
        self.est.sub_enc = local_subscription(
            self.est, EncoderCounts, 'encoders',
            lambda data: lock.call(self.on_encoders, data), QOS_CONTROL)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.est.create_timer(float(self.est.get_parameter('diagnostics_period').value),
                              self.est.publish_diagnostics, clock=steady)
        self.ctrl.create_timer(DIAGNOSTICS_PERIOD, self.ctrl.publish_diagnostics, clock=steady)
        self.finished = False

    def on_encoders(self, data: bytes) -> None:
        """Lock held: one sample through the loop, the command out, then what it produced."""
        est, ctrl = self.est, self.ctrl
        for clock in self.sample_clocks:
            clock(data)
        try:
            header, seq, pc, mc = wire.unpack_encoders(data)
        except (struct.error, IndexError) as exc:   # truncated bytes: counted, nothing else changes
            est.malformed_samples += 1
            est.last_error = f'malformed encoder sample: {exc}'
            return
        now_ns = ctrl.get_clock().now().nanoseconds
        sec, nanosec = wire.header_stamp(header)
        if not ctrl._clock_checked and (sec or nanosec):   # on this process's clock? (said once)
            ctrl._check_clock(sec + nanosec * 1e-9, now_ns * 1e-9)
        if sec == 0 and nanosec == 0:              # an unstamped sample: stamped on arrival
            sec, nanosec = divmod(now_ns, 1_000_000_000)
            header = wire.pack_header(sec, nanosec, wire.header_frame_id(header))
        self.hw.set(seq, pc, mc)
        tick = self.loop.step(now=now_ns * 1e-9, t=sec + nanosec * 1e-9)
        if tick.estimate is None:
            return
        if tick.status is not None:
            u = tick.u if tick.u is not None else 0.0
            if ctrl.publish_result(header, seq, u, tick.status, sec, nanosec) is not None:
                est.align.command(seq, u)
                est.note_command(seq, u)
        est.publish_estimate(header, seq, tick.estimate)

    def start(self) -> None:
        pass

    def close(self) -> None:
        pass

    def exit_status(self) -> int:
        return 0
