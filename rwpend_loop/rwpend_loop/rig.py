"""The loop's process on the rig: the ``driver``, ``estimator`` and ``controller`` nodes around one loop.

    python -m rwpend_loop.host driver [estimator] [controller] [--record DIR] --ros-args ...

The device is the sample clock (rwpend_driver/PROTOCOL.md): it reads the encoders every h and
sends a SAMPLE frame. The driver's link thread is the loop's thread here -- each SAMPLE, as it
is read, is one :meth:`rwpend_loop.loop.Loop.step` holding the loop's lock: the reading (the
counts, and the command the device held over the interval before it, from the frame) -> the
estimator -> the controller -> the driver's claim -> the COMMAND frame written to the port;
then the nodes publish what the sample produced (``encoders``, ``applied``, ``state``,
``joint_states``, ``command``, ``controller/status``) for observers. No message is on the
sample's path, so the command leaves within the computation's time of the frame's arrival.

A controller left out (``--only``, a student's script) is served through the ``command`` topic,
taken by the driver through the same claim. The recorder is a node of this process as on the
simulator (:mod:`rwpend_loop.host`): the sample path's bytes as published, the rest over DDS.
"""
from __future__ import annotations

from typing import Optional

from rwpend_sim.sim_core import Reading


class LinkReading:
    """The serial link as the loop's hardware: :meth:`read` gives the sample the link thread has
    just received (:meth:`set`), with the command the device held over the interval before it
    (its SAMPLE frame: what the motor got, the u of (3.5)/(7.1)); the device integrates in
    real time, so nothing is advanced here."""

    def __init__(self) -> None:
        self.reading: Optional[Reading] = None

    def set(self, seq: int, pc: int, mc: int, u_prev: float) -> None:
        self.reading = Reading(seq, pc, mc, u_prev)

    def read(self) -> Reading:
        return self.reading


class DriverGate:
    """The loop's command gate on the rig: the driver's claim, e-stop and link rules
    (:meth:`rwpend_driver.driver_node.DriverNode._offer`, the one way a command reaches the
    device, for the loop's controller and the ``command`` topic alike). The device holds each
    command over its interval, so :meth:`interval` integrates nothing."""

    def __init__(self, driver) -> None:
        self.driver = driver

    def offer(self, source: int, seq: int, u: float, release: bool = False) -> bool:
        return self.driver._offer(source, seq, u, release)

    def interval(self, late: bool) -> float:
        return 0.0

    def take_event(self) -> None:
        return None


class RigHost:
    """The nodes of the loop's process on the rig (module doc); the same interface as
    :class:`rwpend_loop.host.Host` for :func:`rwpend_loop.host.main`."""

    def __init__(self, names: list[str], record: str | None, writer_process=True) -> None:
        from rwpend_driver.driver_node import DriverNode
        from rwpend_loop.host import LoopLock, build_loop_nodes, tap_publishers
        from rwpend_loop.loop import ControllerStage, Loop
        from rwpend_ros import wire
        from rwpend_ros.params import refuse_undeclared
        self.lock = LoopLock()
        self.driver = DriverNode(loop_lock=self.lock.lock, external_command='controller' not in names)
        self.est, self.ctrl = build_loop_nodes(names, self.lock)
        self.nodes = [n for n in (self.driver, self.est, self.ctrl) if n is not None]
        refuse_undeclared(self.nodes)       # before the recorder opens a bag: a misspelt name is an error
        driver = self.driver
        if self.ctrl is not None:
            from std_msgs.msg import Bool
            ctrl = self.ctrl
            driver.on_estop_change = lambda on: ctrl.on_estop_state(Bool(data=on))
        taps = [(driver, ('pub_enc', 'pub_applied')), (self.est, ('pub_state', 'pub_joints')),
                (self.ctrl, ('pub_cmd', 'pub_status'))]
        self.recorder = None
        if record:
            from rwpend_bag.recorder_node import Recorder
            self.recorder = Recorder(record, None, True, direct=tap_publishers(taps, self._put),
                                     writer_process=writer_process)
            self.nodes.append(self.recorder)
        else:
            tap_publishers(taps, None)
        driver.listeners_here = (self.est is not None) + (self.recorder is not None)
        self.h = float(driver.rig.sample_period)
        self.hardware = LinkReading()
        self.loop = Loop(self.hardware, DriverGate(driver), self.est.stage if self.est else None,
                         ControllerStage(self.ctrl.ctrl, self.ctrl.controller_id) if self.ctrl else None,
                         self.h)
        self._pack_header = wire.pack_header
        #: samples between two /diagnostics of the estimator and the controller, and each one's
        #: turn within them (one node's report per sample at most)
        self.diag_every = [(n, max(1, round(float(n.get_parameter('diagnostics_period').value) / self.h))
                            if n.has_parameter('diagnostics_period') else round(1.0 / self.h))
                           for n in (self.est, self.ctrl) if n is not None]
        driver.loop_hook = self.sample

    def _put(self, topic: str, data: bytes, now_ns: int) -> None:
        self.recorder.writer.put(topic, data, now_ns)
        self.recorder.direct_received += 1

    @property
    def finished(self) -> bool:
        return self.driver.finished

    def sample(self, seq: int, pc: int, mc: int, s, stamp_ns: int) -> None:
        """The link thread, as SAMPLE ``seq`` is read: one loop step (the command written to
        the port), then what it produced published."""
        driver = self.driver
        with self.lock.lock:
            _, u_prev = driver.link.applied(seq, s)
            self.hardware.set(seq, pc, mc, u_prev)
            tick = self.loop.step(t=stamp_ns * 1e-9)
            header = driver.publish_sample(seq, pc, mc, s, stamp_ns)
            if self.est is not None:
                self.est.note_command(seq - 1, u_prev)
                if tick.estimate is not None:
                    self.est.publish_estimate(header, seq, tick.estimate)
                    if self.ctrl is not None and tick.status is not None:
                        sec, nanosec = divmod(stamp_ns, 1_000_000_000)
                        self.ctrl.publish_result(header, seq, tick.u if tick.u is not None else 0.0,
                                                 tick.status, sec, nanosec)
            for i, (node, every) in enumerate(self.diag_every):
                if seq % every == (every - 1 - i) % every:
                    node.publish_diagnostics()

    def start(self) -> None:
        """Nothing to start: the driver's autostart opens the port and starts the link thread."""

    def close(self) -> None:
        """Nothing to stop: the driver's close() ends the link thread, motor at zero."""

    def exit_status(self) -> int:
        return self.driver.exit_status()
