"""The loop's process: the plant, estimator and controller nodes hosted around one loop thread.

    python -m rwpend_loop.host [sim|driver] [estimator] [controller] [--record DIR] [--sim-time]
                               --ros-args -r __ns:=/rwpend --params-file ...

Like ros2_control's controller manager: the nodes ``sim``, ``estimator`` and ``controller`` are
ROS nodes of this process with their names, parameters (validated, live through ``ros2
param``), services and topics, and one thread runs the sample path through them as plain calls
(:class:`rwpend_loop.loop.Loop`): read the encoders, estimate, control, offer the command to the
gate, write it; then the nodes publish what the sample produced (``encoders``, ``sim/true_state``,
``state``, ``joint_states``, ``command``, ``controller/status``) for observers. In real time a
:class:`rwpend_loop.pacer.Pacer` runs it at absolute deadlines (SCHED_FIFO where permitted, from
``RWPEND_RT_PRIORITY``); in lockstep (the simulator's ``lockstep`` parameter) a plain loop runs
it as fast as the CPU goes, and the bag is the same every run.

A node left out of the list runs elsewhere (another process or host): the loop then stops at
the estimate (no controller here: ``state`` goes out, the command comes back on ``command``
through the same gate, claimed) or at the encoders (no estimator either: ``host sim`` is the
simulator alone, ``./rwpend node sim``). In lockstep the loop waits for that command (the
simulator's ``lockstep_timeout``, then u = 0, counted), and for a recorder outside that reports
its progress (the simulator's ``lockstep_recorder_window``). The estimator and the controller
without a plant (``estimator controller``) are the loop's process of the other side:
:mod:`rwpend_loop.control`, one loop step per ``encoders`` message.

``--record DIR``: the recorder of every topic runs in this process, as rosbag2's composable
recorder does: what the hosted nodes publish on the sample path goes into the bag as the bytes
they published (no DDS hop, no second serialisation), written by a child process below the
loop (:mod:`rwpend_bag.procwriter`); every other topic (``/rosout``, ``/parameter_events``,
``estop`` ...) is subscribed over DDS as ``./rwpend record --all`` does. ``/diagnostics``: over
DDS in real time (every process's reports), taken from the hosted nodes in lockstep (their
reports on the sample-time grid: a deterministic bag; those of processes outside this one are
then not in the bag). A sample-path topic goes to DDS only while DDS has subscribers there
(:class:`RecordingPublisher`). ``--sim-time``: log times on the simulated clock (lockstep).

Every callback of a hosted node (parameters, services, timers) runs holding the loop's lock
(:class:`LoopLock`), and so does each sample: a parameter change applies between two samples.
"""
from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
import time

#: the hosted nodes, in the order they are built (the plant first: its gate serves the others)
NODES = ('sim', 'estimator', 'controller')
#: the plants, one of which is hosted: the simulator, or the serial link's driver (rwpend_loop.rig)
PLANTS = ('sim', 'driver')
#: lockstep: the bag writer's queue length at which the loop waits for it (messages)
RECORD_QUEUE_LIMIT = 20_000
#: lockstep: samples between two advances of the hosted nodes' ROS clocks when nothing reads
#: them (:meth:`Host._sync_clocks`)
CLOCK_EVERY = 10
#: lockstep without an external controller: samples run per hold of the loop's lock (a hosted
#: callback -- a parameter change, a service call, a timer -- runs between two batches)
LOCKSTEP_BATCH = 10
#: lockstep, the loop dead: wall s between two looks at the graph for a publisher of command
GRAPH_CHECK_S = 0.25


class LoopLock:
    """The loop's lock, given to the hosted nodes (:class:`rwpend_ros.nodes.LockedCallbacks`):
    their callbacks run holding it, so a parameter change or a service call applies between two
    samples. A condition on a re-entrant lock: the lockstep loop waits on it for an external
    command."""

    def __init__(self) -> None:
        self.lock = threading.Condition(threading.RLock())
        #: called holding the lock before each callback (the host brings the nodes' clocks up
        #: to the newest sample: :meth:`Host._sync_clocks`), or None
        self.before = None

    def call(self, callback, *args, **kwargs):
        with self.lock:
            if self.before is not None:
                self.before()
            return callback(*args, **kwargs)


class RecordingPublisher:
    """A hosted node's publisher on the sample path: its messages go into the in-process bag (``put``:
    the same bytes, at the time they were published; the writer gives the log time) and to DDS
    only while DDS has subscribers (looked up every :data:`LOOK_EVERY` messages: a subscriber
    that comes, a console or ``ros2 topic echo``, gets the messages from then on). A publish
    to nobody still costs rclpy ~10 us, at 7 topics a third of a lockstep sample."""

    LOOK_EVERY = 200

    def __init__(self, pub, put=None) -> None:
        self._pub = pub
        self._put = put
        self.topic = pub.topic_name
        self._n = 0
        self._subscribed = True

    def publish(self, data) -> None:
        self._n += 1
        if self._n >= self.LOOK_EVERY:
            self._n = 0
            self._subscribed = self._pub.get_subscription_count() > 0
        if self._subscribed or not isinstance(data, (bytes, bytearray)):
            self._pub.publish(data)
        if self._put is not None and isinstance(data, (bytes, bytearray)):
            self._put(self.topic, wire_bytes(data), time.time_ns())

    def __getattr__(self, name):
        return getattr(self._pub, name)


def wire_bytes(data) -> bytes:
    """The bytes as a subscriber takes them from DDS: Fast DDS pads a serialized payload with
    zeros to a multiple of 4 bytes, so a bag recorded here is the bag a recorder in another
    process records, byte for byte."""
    pad = -len(data) % 4
    return bytes(data) + b'\0' * pad if pad else bytes(data)


def build_loop_nodes(names: list[str], lock: LoopLock, plant_here: bool = True) -> tuple:
    """The hosted ``estimator`` and ``controller`` nodes of ``names`` (None where left out),
    their callbacks under ``lock``; the estimator with its loop stage. ``plant_here``: the
    plant is a node of this process too (rwpend_control.controller_node)."""
    from rwpend_loop.loop import EstimatorStage
    est = ctrl = None
    if 'estimator' in names:
        from rwpend_estimation.estimator_node import EstimatorNode
        est = EstimatorNode(loop_lock=lock, hosted=True)
        est.stage = EstimatorStage(est.est)
    if 'controller' in names:
        from rwpend_control.controller_node import ControllerNode
        ctrl = ControllerNode(loop_lock=lock, hosted=True, plant_here=plant_here)
    return est, ctrl


def tap_publishers(taps, put) -> dict:
    """Wrap the publishers ``taps`` = [(node or None, attribute names)] of hosted nodes in a
    :class:`RecordingPublisher` (``put``: into the bag, None: not recorded); returns {topic:
    (type name, offered QoS)} for the recorder ({} when not recorded: the recorder's modules
    are then not imported)."""
    pubs = [(node, attr, pub) for node, attrs in taps if node is not None for attr in attrs
            if (pub := getattr(node, attr, None)) is not None]
    for node, attr, pub in pubs:
        setattr(node, attr, RecordingPublisher(pub, put))
    if put is None:
        return {}
    from rwpend_bag.recorder_node import qos_dict
    return {pub.topic_name: (f'{pub.msg_type.__module__.split(".")[0]}/msg/{pub.msg_type.__name__}',
                             [qos_dict(pub.qos_profile)]) for _, _, pub in pubs}


class Host:
    """The nodes of this process and the loop that runs through them (the simulator's; the
    rig's: :class:`rwpend_loop.rig.RigHost`)."""

    def __init__(self, names: list[str], record: str | None, sim_time: bool, writer_process=True) -> None:
        from rwpend_ros.params import refuse_undeclared
        from rwpend_sim.sim_node import SimNode
        from rwpend_loop.loop import ControllerStage, Loop
        self.lock = LoopLock()
        self.sim = SimNode(self.lock, external_command='controller' not in names)
        self.est, self.ctrl = build_loop_nodes(names, self.lock)
        self.nodes = [n for n in (self.sim, self.est, self.ctrl) if n is not None]
        refuse_undeclared(self.nodes)       # before the recorder opens a bag: a misspelt name is an error
        if self.ctrl is not None:
            from std_msgs.msg import Bool
            ctrl = self.ctrl
            self.sim.on_estop_change = lambda on: ctrl.on_estop_state(Bool(data=on))
        self.recorder = None
        if record:
            from rwpend_bag.recorder_node import Recorder
            self.recorder = Recorder(record, None, True, sim_time=sim_time, direct=self._tap(self._put),
                                     writer_process=writer_process)
            self.nodes.append(self.recorder)
        else:
            self._tap(None)
        sim = self.sim
        #: lockstep: the simulator's ROS time from its own samples (rwpend_ros.simtime), as the
        #: estimator's and the controller's: no /clock subscription of its own, so /clock goes to
        #: DDS only for readers outside the process (one DDS message and callback less per sample)
        self.sim_clock = None
        if sim.lockstep and sim.get_parameter('use_sim_time').value is True:
            from rwpend_ros.simtime import SampleTime
            self.sim_clock = SampleTime(sim)
        from functools import partial

        from rclpy.clock import ClockType
        from rclpy.time import Time

        from rwpend_ros import wire
        self._ros_time = partial(Time, clock_type=ClockType.ROS_TIME)
        self._pack_header = wire.pack_header
        #: the hosted nodes' lockstep clocks, advanced together to the samples' stamps
        self.sample_clocks = [c for c in (self.sim_clock, getattr(self.est, 'sample_time', None),
                                          getattr(self.ctrl, 'sample_time', None)) if c is not None]
        self._stamp_ns = -1             # the stamp of the newest sample published
        self._clock_ns = -1             # ... the clocks were last advanced to
        if self.sample_clocks:
            self.lock.before = self._sync_clocks
        self.h = sim.h
        self.period_ns = sim.period_ns
        self.loop = Loop(sim.hw, sim.gate, self.est.stage if self.est else None,
                         ControllerStage(self.ctrl.ctrl, self.ctrl.controller_id) if self.ctrl else None,
                         self.h)
        #: samples between two /diagnostics of each node (its diagnostics_period), and the
        #: sample of each node's turn within it (spread: one node's report per sample at most)
        self.diag_every = [(n, max(1, round(n.p['diagnostics_period'] / self.h)) if n is sim else
                            max(1, round(float(n.get_parameter('diagnostics_period').value) / self.h))
                            if n.has_parameter('diagnostics_period') else round(1.0 / self.h))
                           for n in (sim, self.est, self.ctrl) if n is not None]
        self.stop = threading.Event()
        self._command_publisher = True      # lockstep: a publisher of command (checked when dead)
        self._graph_checked_at = -math.inf
        self.pacer = None
        self.thread = threading.Thread(target=self._run, name='loop', daemon=True)

    def _tap(self, put) -> dict:
        """The sample-path and status publishers of the hosted nodes into the bag
        (:func:`tap_publishers`); ``/diagnostics`` too in lockstep (its reports then come on the
        sample-time grid: a deterministic bag); in real time the recorder subscribes to it, so
        the reports of every process are in the bag."""
        diag = ('pub_diag',) if self.sim.lockstep else ()
        return tap_publishers([(self.sim, ('pub_enc', 'pub_true', 'pub_clock', *diag)),
                               (self.est, ('pub_state', 'pub_joints', *diag)),
                               (self.ctrl, ('pub_cmd', 'pub_status', *diag))], put)

    def _put(self, topic: str, data: bytes, now_ns: int) -> None:
        self.recorder.writer.put(topic, data, now_ns)
        self.recorder.direct_received += 1

    # ------------------------------------------------------------------ the loop thread
    def _wait_for_start(self) -> None:
        """Hold sample 0 until the parts outside this process are there: the subscribers the
        simulator's ``start.*_subscribers`` ask for (a recorder of its own), an external
        estimator (a subscriber of encoders), in lockstep an external controller (a publisher of
        command and a subscriber of state); then the simulator's ``start.delay`` for discovery to
        settle -- except in lockstep with nothing outside awaited (the whole sample path and the
        recorder here: the delay would change nothing but the wall time). A recorder outside
        that the lockstep run keeps pace with takes ``/clock`` (its progress)."""
        sim = self.sim
        enc_topic = sim.resolve_topic_name('encoders')
        # start.encoders_subscribers counts the estimator (here, when hosted) and a recorder
        n_enc = max(0, sim.p['start.encoders_subscribers'] - (self.est is not None))
        n_true = sim.p['start.true_state_subscribers']
        # a recorder of command (the controller in another process), besides the simulator's own
        n_cmd = sim.p['start.command_subscribers']
        cmd_topic = sim.resolve_topic_name('command')
        # lockstep: start.state_subscribers counts the controller (here, when hosted) and the
        # subscribers of state outside (a console whose page must be open before sample 0)
        n_state = max(0, sim.p['start.state_subscribers'] - (self.ctrl is not None)) if sim.lockstep else 0
        said = time.monotonic()
        while not self.stop.is_set():
            missing = []
            if sim.count_subscribers(enc_topic) < n_enc:
                missing.append(f'{n_enc} subscribers of encoders')
            if sim.count_subscribers(sim.resolve_topic_name('sim/true_state')) < n_true:
                missing.append(f'{n_true} subscribers of sim/true_state')
            if sim.count_subscribers(sim.resolve_topic_name('state')) < n_state:
                missing.append(f'{n_state} subscribers of state')
            if n_cmd and sim.count_subscribers(cmd_topic) - (sim.sub_cmd is not None) < n_cmd:
                missing.append(f'{n_cmd} subscribers of command besides the simulator')
            if self.ctrl is None and sim.lockstep:   # (real time: the plant runs without one)
                if sim.count_publishers(cmd_topic) == 0:
                    missing.append('a publisher of command')
                if self.est is not None and sim.count_subscribers(sim.resolve_topic_name('state')) == 0:
                    missing.append('a subscriber of state')
            if sim.recorder_window and sim.pub_clock.get_subscription_count() == 0:
                missing.append('the recorder (a subscriber of /clock)')
            if not missing:
                break
            if time.monotonic() - said >= sim.p['diagnostics_period']:
                said = time.monotonic()
                with self.lock.lock:           # no failure is silent: what sample 0 waits for
                    sim.waiting_for = ', '.join(missing)
                    sim.publish_diagnostics()
            time.sleep(0.02)
        sim.waiting_for = ''
        outside = n_enc or n_true or n_state or n_cmd or self.est is None or self.ctrl is None or sim.recorder_window
        if outside or not sim.lockstep:
            time.sleep(sim.p['start.delay'])
        sim.wall_start = time.monotonic()

    def _run(self) -> None:
        try:
            self._wait_for_start()
            if self.sim.lockstep:
                self._run_lockstep()
            else:
                self._run_realtime()
        except Exception:  # noqa: BLE001 - the context may be gone at SIGINT
            if self.sim.context.ok() and not self.stop.is_set():
                raise
        finally:
            with self.lock.lock:
                self.sim.finish()
                self.finished = True
            if self.wake is not None:
                try:
                    self.wake()
                except Exception:  # noqa: BLE001 - the executor already gone (SIGINT): none to wake
                    pass

    finished = False
    #: called once the run has finished (main: the executor's ``wake``, so its spin ends now,
    #: not at the end of its wait: 0-100 ms of every run's wall time)
    wake = None

    def _sample(self, k: int, stamp_ns: int, behind=None) -> bool:
        """Lock held: sample k through the loop, then published; False when the run is done."""
        sim, loop = self.sim, self.loop
        external = self.ctrl is None
        if loop.interval_pending:
            late = external and sim.core.u_seq < sim.core.k     # the command of the last sample did not come
            was = sim.core.timed_out
            loop.finish_interval(late=late)
            self._after_interval(was)
        if sim.done():
            return False
        was = sim.core.timed_out
        tick = loop.step(behind=behind, t=stamp_ns * 1e-9)
        if tick.taken and sim.trace is not None:     # the plant holds command k from now (the
            sim.trace('sim.rx', tick.reading.seq)     # external controller's: sim_node's callback)
        if tick.late:
            self._after_interval(was)
        self._publish(tick, stamp_ns)
        return True

    def _after_interval(self, was_timed_out: bool) -> None:
        sim = self.sim
        event = sim.gate.take_event()
        if event is not None:
            sim._report(event)
        elif sim.core.timed_out and not was_timed_out:
            sim.publish_diagnostics()

    def _publish(self, tick, stamp_ns: int) -> None:
        """What sample k produced, for observers (after the command is written)."""
        sim = self.sim
        enc = sim.publish_sample(stamp_ns, tick.reading)
        seq = tick.reading.seq
        if self.sample_clocks:
            self._stamp_ns = stamp_ns
            if seq % CLOCK_EVERY == 0:
                self._sync_clocks()
        sim.steps += 1
        if self.est is not None:
            self._publish_loop_nodes(tick, stamp_ns, enc)
        for i, (node, every) in enumerate(self.diag_every):
            if seq % every == (every - 1 - i) % every:     # on the sample time grid: deterministic
                if self.sample_clocks:
                    self._sync_clocks()
                node.publish_diagnostics()

    def _sync_clocks(self) -> None:
        """Lockstep, lock held: the hosted nodes' ROS time (rwpend_ros.simtime.SampleTime) to the
        stamp of the newest sample. rclpy's clock override costs ~20 us per sample for three
        nodes in this process (it wakes the executor), so it is done only where the time is read
        -- before a node's /diagnostics and before any callback of a hosted node (parameters,
        services, timers: :class:`LoopLock`), which see the time they would see with an advance
        per sample -- and every :data:`CLOCK_EVERY` samples for timers on the ROS clock (the
        controller's parameter sync, 20 Hz, then fires up to CLOCK_EVERY samples later)."""
        ns = self._stamp_ns
        if ns != self._clock_ns and ns >= 0:
            self._clock_ns = ns
            t = self._ros_time(nanoseconds=ns)
            for clock in self.sample_clocks:
                clock.set_time(ns, t)

    def _publish_loop_nodes(self, tick, stamp_ns: int, enc: bytes) -> None:
        sim = self.sim
        if tick.reading.seq > 0:
            self.est.note_command(tick.reading.seq - 1, tick.reading.u_prev)
        e = tick.estimate
        if e is None:
            return
        sec, nanosec = divmod(stamp_ns, 1_000_000_000)
        header = self._pack_header(sec, nanosec, sim.frame_id)
        self.est.publish_estimate(header, tick.reading.seq, e)
        if self.ctrl is not None and tick.status is not None:
            self.ctrl.publish_result(header, tick.reading.seq, tick.u if tick.u is not None else 0.0,
                                     tick.status, sec, nanosec)

    def _run_realtime(self) -> None:
        from rwpend_loop.pacer import Pacer
        self.pacer = pacer = Pacer(self.period_ns)
        t0_ros = self.sim.get_clock().now().nanoseconds
        period = self.period_ns

        trace = self.sim.trace

        def tick(k: int) -> bool:
            if trace is not None:
                trace('sim.tick', k, pacer.deadline(k))
            with self.lock.lock:
                return self._sample(k, t0_ros + k * period, behind=pacer.behind)
        pacer.run(tick, self.stop)
        self.sim.overruns = pacer.overruns

    def _run_lockstep(self) -> None:
        sim = self.sim
        period = self.period_ns
        external = self.ctrl is None
        writer = self.recorder.writer if self.recorder is not None else None
        k = 0
        cond = self.lock.lock
        # nothing outside waits for each sample: the lock is held for LOCKSTEP_BATCH samples, so
        # a callback waiting for it (a timer, a parameter change) is woken once per batch, not
        # once per sample (each wake-up cost the loop ~10 % of its time in the GIL's hand-over)
        batch = 1 if external else LOCKSTEP_BATCH
        running = True
        while running and not self.stop.is_set():
            with cond:
                for _ in range(batch):
                    if sim.recorder_behind(k):
                        self._hold_for_recorder(k)
                    if sim.trace is not None:
                        sim.trace('sim.tick', k)
                    if not self._sample(k, k * period):
                        running = False
                        break
                    if external:
                        self._await_command(k)
                    k += 1
                    if self.stop.is_set() or (writer is not None and writer.queue_size() > RECORD_QUEUE_LIMIT):
                        break
            if writer is not None and writer.queue_size() > RECORD_QUEUE_LIMIT:
                while writer.queue_size() > RECORD_QUEUE_LIMIT // 2 and not self.stop.is_set():
                    time.sleep(0.001)        # the bag writer catches up: nothing is lost

    def _hold_for_recorder(self, k: int) -> None:
        """Lockstep, lock held: sample k waits until the recorder outside has reported sample
        k - W (the simulator's ``lockstep_recorder_window`` W); after
        ``lockstep_recorder_timeout`` wall seconds without a report the run goes on without it
        (said at once, on /diagnostics too: the bag may then miss messages)."""
        sim = self.sim
        sim.recorder_holds += 1
        hold = time.monotonic()
        limit = sim.p['lockstep_recorder_timeout']
        while sim.recorder_behind(k) and not self.stop.is_set():
            remaining = max(sim.recorder_wall, hold) + limit - time.monotonic()
            if remaining <= 0:
                sim.get_logger().error(
                    f'lockstep: the recorder reported no progress for {limit:g} s while '
                    f'{k - sim.recorder_k} samples behind; running on without waiting for it '
                    '(the bag may miss messages)')
                sim.recorder_window = 0
                sim.recorder_given_up = True
                sim.publish_diagnostics()
                break
            self.lock.lock.wait(remaining)
        sim.recorder_hold_s += time.monotonic() - hold

    def _await_command(self, k: int) -> None:
        """Lockstep, lock held: wait for the external controller's command answering k
        (``lockstep_timeout`` of wall time; sample 0 ``start.first_command_timeout``)."""
        sim = self.sim
        limit = sim.p['lockstep_timeout'] if k else sim.p['start.first_command_timeout']
        if sim.health.dead and not self._command_publisher_there():
            limit = 0.0        # the controller is gone: the run goes on at u = 0 without waiting
        deadline = time.monotonic() + limit
        while sim.core.u_seq < k and not self.stop.is_set():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                if k == 0:
                    sim.get_logger().warn(f'lockstep: no command for sample 0 within {limit:g} s; '
                                          'running with u = 0')
                sim.core.counters.late_commands += 1
                sim.core.no_command()
                was = sim.core.timed_out
                self.loop.finish_interval(late=True)
                self._after_interval(was)
                return
            self.lock.lock.wait(remaining)

    def _command_publisher_there(self) -> bool:
        """Lockstep, the loop dead: is there still a publisher of ``command`` (a stalled
        controller, which may come back) or none (killed, ended: its samples would each wait
        ``lockstep_timeout`` in vain, 0.5 s of wall time per simulated ms)? Asked of the ROS graph
        at most every :data:`GRAPH_CHECK_S` s; the change is said once each way."""
        now = time.monotonic()
        if now - self._graph_checked_at >= GRAPH_CHECK_S:
            self._graph_checked_at = now
            sim = self.sim
            there = sim.count_publishers(sim.resolve_topic_name('command')) > 0
            if there != self._command_publisher:
                self._command_publisher = there
                if there:
                    sim.get_logger().info('lockstep: a publisher of command is back; each sample waits '
                                          'for its command again')
                else:
                    sim.get_logger().warn('lockstep: the loop is dead and no node publishes command any '
                                          'more; the run goes on at u = 0 without waiting for one')
        return self._command_publisher

    # ------------------------------------------------------------------ life
    def start(self) -> None:
        self.thread.start()

    def close(self) -> None:
        self.stop.set()
        with self.lock.lock:
            self.lock.lock.notify_all()
        if self.thread.is_alive():
            self.thread.join(timeout=2.0)

    def exit_status(self) -> int:
        return self.sim.exit_status()


def parse_args(argv: list[str]) -> tuple[argparse.Namespace, list[str]]:
    ros = []
    if '--ros-args' in argv:
        i = argv.index('--ros-args')
        argv, ros = argv[:i], argv[i:]
    p = argparse.ArgumentParser(prog='rwpend_loop.host', description=__doc__.split('\n\n')[0])
    p.add_argument('nodes', nargs='*', default=list(NODES), help='the hosted nodes (the plant, sim or '
                   'driver, first; without a plant: estimator controller, fed by the encoders topic)')
    p.add_argument('--record', metavar='DIR', help='record every topic into the bag DIR, in this process')
    p.add_argument('--sim-time', action='store_true', help='log times on the simulated clock (lockstep)')
    a = p.parse_args(argv)
    known = PLANTS + NODES[1:]
    bad = [n for n in a.nodes if n not in known]
    plants = [n for n in a.nodes if n in PLANTS]
    if not plants and sorted(a.nodes) == ['controller', 'estimator']:
        if a.record or a.sim_time:
            p.error('--record and --sim-time need the plant in this process (a recorder of its own: '
                    './rwpend record)')
        return a, ros
    if bad or len(set(a.nodes)) != len(a.nodes) or len(plants) != 1:
        p.error(f'nodes must be distinct names of {", ".join(known)} with one plant (sim or driver), '
                f'or estimator controller without a plant, got {" ".join(a.nodes)}')
    if 'driver' in a.nodes and a.sim_time:
        p.error('--sim-time needs the simulator: the rig runs in real time')
    if 'controller' in a.nodes and 'estimator' not in a.nodes:
        p.error('a hosted controller needs the hosted estimator (the loop runs estimator -> controller)')
    return a, ros


def dump_traces(nodes) -> None:
    """Write the trace of every node that has one (rwpend_ros.trace: RWPEND_TRACE set), as
    :func:`rwpend_ros.runner.run_node` does for a node of its own; an error is printed."""
    for node in nodes:
        trace = getattr(node, 'trace', None)
        if trace is not None:
            try:
                trace.dump()
            except OSError as exc:
                print(f'trace of {node.get_name()} not written: {exc}', file=sys.stderr, flush=True)


def main(argv=None) -> int:
    """Build the nodes, run the executor in this thread and the loop in its own until SIGINT /
    SIGTERM or the simulator's ``duration``; returns the exit status (2: a bad parameter, 3: the
    loop was dead at the end)."""
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.signals import SignalHandlerOptions

    from rwpend_ros.params import ConfigError
    from rwpend_ros.runner import apply_thread_priority, close_nodes, freeze_gc, make_executor, spin_executor
    from rwpend_ros.sched import apply_scheduling
    from rwpend_ros.transport import apply_transport_or_exit
    a, ros = parse_args(sys.argv[1:] if argv is None else list(argv))
    apply_transport_or_exit()
    apply_scheduling()
    # the loop thread must get the GIL within a fraction of a sample when it wakes
    sys.setswitchinterval(0.0002)
    # the bag writer's child starts now, its interpreter and imports beside this process's own
    # (after apply_scheduling: it takes its priority from this process's)
    ahead = None
    if a.record:
        from rwpend_bag.procwriter import start_process
        ahead = start_process()
    rclpy.init(args=[sys.argv[0], *ros], signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    old = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    host = None
    status = 0
    try:
        if 'driver' in a.nodes:
            from rwpend_loop.rig import RigHost
            host = RigHost(a.nodes, a.record, writer_process=ahead or True)
        elif 'sim' not in a.nodes:
            from rwpend_loop.control import ControlHost
            host = ControlHost(a.nodes)
        else:
            host = Host(a.nodes, a.record, a.sim_time, writer_process=ahead or True)
        apply_thread_priority(host.nodes)       # before the loop's thread starts: it inherits it
        executor = make_executor()
        for node in host.nodes:
            executor.add_node(node)
        freeze_gc()
        host.wake = getattr(executor, 'wake', None)
        host.start()
        spin_executor(executor, until=lambda: stop.is_set() or host.finished)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ConfigError as exc:
        print(f'error: {exc}', file=sys.stderr, flush=True)
        status = 2
    finally:
        if host is not None:
            host.close()
            close_nodes(host.nodes)
            dump_traces(host.nodes)
            for node in host.nodes:
                try:
                    node.destroy_node()
                except Exception:  # noqa: BLE001
                    pass
        if ahead is not None:
            # told its bag and closed by the recorder above, or never told (a bad parameter):
            # its pipe closed, the child ends without writing anything
            ahead.conn.close()
            ahead.proc.join(timeout=5.0)
        rclpy.try_shutdown()
        for sig, h in old.items():
            signal.signal(sig, h)
    if status == 0 and host is not None:
        status = host.exit_status()
    return status


if __name__ == '__main__':
    raise SystemExit(main())
