"""The rig path of the lab (``--plant serial:PORT``): each run in real time through the driver, the
book's manual steps asked of the student and detected from the encoders.

For every :class:`rwpend_lab.experiment.Run` the stack of ``./rwpend up --plant serial:PORT
--record BAG --params FILE`` is started (up's defaults: the real-time priority where permitted,
the loop's process with the driver as its plant, rwpend_loop.rig), with the controller ``off`` when the run arms it later
(``Run.arm_after``).  A monitor node in this process takes the encoder samples and feeds them to
:class:`rwpend_lab.manual.StepSequence`, which says when to print each prompt (``>>> ...``), when
a step was seen, when to switch the controller to the run's mode (a ``set_parameters`` call, as
``./rwpend param set controller mode ...``); :class:`rwpend_lab.arming.Arming` says when that call is
made again and when the run is over; then the stack is stopped.
The recorded run is cut to what the simulator run holds (:func:`rwpend_lab.data.trim`, from the
origin the steps give) and analysed as on the simulator.

With ``./rwpend emulate --hand`` the student's hand is a line on the emulator's stdin (``steady
1``, ``lift 20 1``, ``lift 180 1``, ``tap 0.8``): the tests drive it from the prompts.
"""
from __future__ import annotations

import os
import queue
import sys
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

from . import runner
from .data import first_command, load_run, trim
from .arming import Arming
from .experiment import LabError, Run
from .manual import StepSequence

#: wall seconds for the stack to start, besides the steps and the run
START_S = 30.0
#: seconds a prompt waits for its step before the run is given up
PROMPT_TIMEOUT_S = 120.0
#: the share of the run's samples the cut bag must hold
MIN_SHARE = 0.9


class Monitor:
    """The live part of one rig run: a ROS node in a thread of its own that feeds the encoder
    samples to the run's :class:`StepSequence`, prints its prompts and arms the controller."""

    def __init__(self, steps: StepSequence, ns: str, mode: str, log, rt_priority: int = 0,
                 recorder_in_loop: bool = True) -> None:
        self.steps, self.ns, self.mode, self._log = steps, ns, mode, log
        self.rt_priority = rt_priority
        #: the loop's process records the loop's topics itself: nobody else to wait for
        self.listeners = {} if recorder_in_loop else self.LISTENERS
        self.command_seq = -1          # the newest sample the controller answered
        #: the arming call and the run's end; the run's time starts when the mode came into force
        #: (the call answered), whatever sample this monitor had reached by then
        self.arming = Arming(steps.duration_n * steps.h)
        self.events: queue.SimpleQueue = queue.SimpleQueue()
        self.error = ''
        self.done = threading.Event()
        self.stop = threading.Event()
        self.samples = 0
        self.listening = False
        self.thread = threading.Thread(target=self._run, name='lab-monitor', daemon=True)
        self.ready = threading.Event()

    def start(self) -> None:
        self.thread.start()
        if not self.ready.wait(20.0):
            raise LabError('the lab monitor did not start within 20 s')
        if self.error:
            raise LabError(self.error)

    def log(self, text: str) -> None:
        self._log(text)
        sys.stdout.flush()       # a prompt is read by a person (or a test's hand) at once

    def finished(self) -> bool:
        return self.done.is_set()

    @property
    def arm_retries(self) -> int:
        return self.arming.retries

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=10.0)

    def _on_command(self, data: bytes) -> None:
        from rwpend_ros import wire
        try:
            self.command_seq = max(self.command_seq, wire.unpack_command(data)[0])
        except Exception:  # noqa: BLE001 - malformed bytes: not a command
            pass

    def _on_encoders(self, data: bytes) -> None:
        from rwpend_ros import wire
        if not self.listening:
            return                     # the steps start once the whole run is recorded
        try:
            _, seq, pc, mc = wire.unpack_encoders(data)
        except Exception:  # noqa: BLE001 - malformed bytes: not a sample
            return
        self.samples += 1
        for ev in self.steps.feed(seq, pc, mc):
            self.events.put(ev)

    #: subscribers each loop topic has once the run is recorded, in a layout whose recorder is a
    #: process of its own: encoders (the estimator, the recorder, this monitor), state (the
    #: controller, the recorder), command (the driver, the recorder, this monitor),
    #: controller/status (the recorder)
    LISTENERS = {'encoders': 3, 'state': 2, 'command': 3, 'controller/status': 1}

    def _not_recorded(self, node, tool) -> str:
        """'' once every loop topic has its subscribers (the recorder among them), else which not."""
        short = [f'{t} has {have} of {need} subscribers' for t, need in self.listeners.items()
                 if (have := node.count_subscribers(tool.fqn(t))) < need]
        return '; '.join(short)

    def _run(self) -> None:
        from rcl_interfaces.srv import SetParameters
        from rwpend_msgs.msg import EncoderCounts, MotorCommand
        from rwpend_ros.qos import QOS_CONTROL
        from rwpend_ros.runner import make_executor
        from rwpend_ros.tools import RosTool
        if self.rt_priority > 0:
            # below the loop (its processes run at rt_priority), above ordinary load: a monitor that
            # falls behind the samples shows the prompts late and arms the controller late; set
            # before rclpy.init, so the DDS threads of this context inherit it
            try:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(max(1, self.rt_priority - 20)))
            except (OSError, AttributeError):
                pass
        try:
            with RosTool(self.ns) as tool:
                node = tool.node
                node.create_subscription(EncoderCounts, tool.fqn('encoders'), self._on_encoders,
                                         QOS_CONTROL, raw=True)
                node.create_subscription(MotorCommand, tool.fqn('command'), self._on_command, QOS_CONTROL, raw=True)
                setter = node.create_client(SetParameters, tool.fqn('controller') + '/set_parameters')
                # one executor for the whole run: rclpy.spin_once(node) would add and remove
                # the node on every call, slower than the samples come
                executor = make_executor()
                executor.add_node(node)
                self.ready.set()
                self._watch(executor, tool, setter)
                executor.remove_node(node)
                executor.shutdown(timeout_sec=1.0)
        except Exception as exc:  # noqa: BLE001 - said to the runner, which stops the stack
            self.error = f'lab monitor: {exc}'
            self.done.set()
        finally:
            self.ready.set()

    def _watch(self, executor, tool, setter) -> None:
        """Until the run is over or stopped: spin, check the start, carry the arming call (asked,
        re-asked while unanswered, answered), and act on the steps' events."""
        started = time.monotonic()
        self._call, self._request = None, None      # the arming call in flight, and its request
        arming = self.arming
        while not self.stop.is_set() and not self.done.is_set():
            executor.spin_once(timeout_sec=0.05)
            self._check_start(tool, started)
            if self._call is not None and not self._call.done() and arming.unanswered(time.monotonic()):
                self._call = setter.call_async(self._request)
            if self._call is not None and self._call.done() and self._arming_answered(setter):
                continue
            if arming.over(time.monotonic(), self.command_seq, self.steps.end):
                self.done.set()
            self._take_events(tool, setter)

    def _check_start(self, tool, started: float) -> None:
        """An error when the stack is not listening, or no sample came, START_S s after the start."""
        late = time.monotonic() - started > START_S
        if not self.listening:
            missing = self._not_recorded(tool.node, tool)
            self.listening = not missing
            if missing and late:
                self.error = (f'the stack was not ready within {START_S:g} s: {missing} (see the '
                              f'log of the run)')
                self.done.set()
        elif self.samples == 0 and late:
            self.error = (f'no encoder sample from the driver within {START_S:g} s (is the rig '
                          f'connected and powered? the driver\'s log says why)')
            self.done.set()

    def _arming_answered(self, setter) -> bool:
        """The controller answered the arming call: armed, refused (an error) or to be asked
        again (True: asked again after the retry pause)."""
        result = self._call.result()
        ok = bool(result is not None and result.results and result.results[0].successful)
        why = result.results[0].reason if result is not None and result.results else 'no answer'
        answer = self.arming.answered(ok, why, self.mode, time.monotonic())
        self._call = None
        if answer == 'again':
            time.sleep(self.arming.retry_pause_s)
            self._call = setter.call_async(self._request)
            return True
        if answer == 'refused':
            self.error = self.arming.error
            self.done.set()
        else:
            self.log(f'          controller: mode {self.mode} (sample {self.arming.armed_seq})')
        return False

    def _take_events(self, tool, setter) -> None:
        """The steps' events: prompts shown, steps seen, the controller armed, a timeout, the end."""
        from rcl_interfaces.msg import Parameter
        from rcl_interfaces.srv import SetParameters
        from rwpend_ros.tools import to_parameter_value
        while not self.events.empty():
            ev = self.events.get_nowait()
            if ev.kind == 'show':
                self.log(f'      >>> {ev.text}')
            elif ev.kind == 'detected':
                self.log(f'          seen (sample {ev.seq})')
            elif ev.kind == 'arm':
                if not setter.service_is_ready():
                    self.error = f'{tool.fqn("controller")}/set_parameters is not available'
                    self.done.set()
                    return
                self._request = SetParameters.Request(parameters=[
                    Parameter(name='mode', value=to_parameter_value(self.mode))])
                self.arming.ask(ev.seq, time.monotonic())
                self._call = setter.call_async(self._request)
            elif ev.kind == 'timeout':
                self.error = ev.text
                self.done.set()
            elif ev.kind == 'done':
                self.arming.steps_done(time.monotonic())


def armed_origin(d, arm_seq: int, mode: str) -> int:
    """The t = 0 of a run whose last step armed the controller: its first command in ``mode``
    (controller/status, every 10 samples, says from when; the first non-zero command then says
    exactly), at or after the sample the arming was asked on."""
    t_arm = (arm_seq - d.seq0) * d.h
    switched = [t for t, m, *_ in d.switches if m == mode and t >= t_arm - 0.05]
    seq = arm_seq if not switched else max(arm_seq, d.seq0 + int(round(switched[0] / d.h)) - 10)
    return first_command(d, seq)


@dataclass
class RigRun:
    """What :func:`record_run` did: the bag, the steps as detected, the monitor's counts."""

    bag: Path
    steps: StepSequence
    armed: bool
    wall_s: float
    monitor_samples: int
    arm_retries: int


def port_problem(plant: str) -> str | None:
    """Why ``serial:PORT`` cannot be a rig's link (the port is not there), or None."""
    port = plant.split(':', 1)[1]
    if not Path(port).exists():
        return f'{plant}: {port} does not exist (the rig\'s serial device, or the emulator\'s --link path)'
    return None


def record_run(run: Run, rig, out: Path, stack, log=print, prog: str = 'rwpend lab',
               error=LabError) -> RigRun:
    """One run on the rig, recorded to ``out/runs/<name>``: ``stack`` (a
    :class:`rwpend_bringup.stack.Stack` with a serial plant, e.g. :func:`rwpend_lab.runner.base_stack`)
    with the recorder, the steps prompted and detected, the controller armed when they say, the
    stack stopped when the run is over. ``error`` (an exception class) carries the reason when it
    cannot be done. Shared by the lab and ``./rwpend identify --plant serial:``."""
    from rwpend_bringup.launch import Launcher
    from rwpend_bringup.stack import plan
    why = port_problem(stack.plant)
    if why:
        raise error(why)
    runs_dir = out / 'runs'
    runs_dir.mkdir(parents=True, exist_ok=True)
    bag = runs_dir / run.name
    if bag.exists():
        raise error(f'{bag} exists already (choose a new --out directory)')
    armed = run.arm_after > 0 and run.mode != 'off'
    pfile = runner.params_file(replace(run, mode='off') if armed else run,
                               runs_dir / f'{run.name}.params.yaml', stack.plant)
    # the driver publishes once the estimator, the recorder and the lab's monitor listen
    overrides = {**stack.overrides,
                 'driver': {'start.encoders_subscribers': 3, **stack.overrides.get('driver', {})}}
    try:
        p = plan(replace(stack, record=str(bag), params_files=(*stack.params_files, str(pfile)),
                         overrides=overrides))
        steps = StepSequence(rig, run.prompts, run.arm_after if armed else 0, run.duration,
                             timeout_s=PROMPT_TIMEOUT_S)
    except ValueError as exc:
        raise error(str(exc)) from None
    for note in p.notes:
        log(f'      {note}')
    ua = p.stack
    monitor = Monitor(steps, ua.ns, run.mode, log, ua.rt_priority or 0, recorder_in_loop=ua.layout == 'loop')
    try:
        monitor.start()
    except LabError as exc:
        raise error(str(exc)) from None
    bound = START_S + run.duration + sum(PROMPT_TIMEOUT_S + p.wait_s for p in run.prompts)
    t0 = time.monotonic()
    log_file = runs_dir / f'{run.name}.log'
    try:
        with open(log_file, 'w') as fh:
            launcher = Launcher(p.specs, namespace=ua.ns, params_files=p.files, out=fh)
            status = launcher.run(bound, until=monitor.finished)
    finally:
        monitor.close()
    if monitor.error:
        raise error(f'run {run.name}: {monitor.error}; see {log_file}')
    if launcher.reason != 'until' or status != 0:
        why = {'duration': f'no end within {bound:g} s', 'signal': 'interrupted'}.get(launcher.reason,
                                                                                     launcher.reason)
        raise error(f'run {run.name}: the stack stopped before the run was over ({why}; '
                    f'{monitor.samples} samples seen); see {log_file}')
    return RigRun(bag, steps, armed, time.monotonic() - t0, monitor.samples, monitor.arm_retries)


def run_one(exp, run: Run, rig, out: Path, options, log) -> tuple[object, dict]:
    """One run of an experiment on the rig; (RunData cut to what the simulator run holds, its record)."""
    r = record_run(run, rig, out, runner.base_stack(options.sets, plant=options.plant), log=log)
    d = load_run(r.bag, rig.sample_period)
    origin = r.steps.origin
    if r.armed and run.arm_after == len(run.prompts):
        origin = armed_origin(d, origin, run.mode)
    try:
        cut = trim(d, origin, run.duration)
    except ValueError as exc:
        raise LabError(f'run {run.name}: {exc}') from None
    need = MIN_SHARE * run.duration / rig.sample_period
    if cut.n < need:
        raise LabError(f'run {run.name}: the bag holds {cut.n} samples from the origin, {int(need)} needed')
    return cut, {**runner.run_record(run, r.bag, r.wall_s), **run_facts(r, options.plant, origin, rig.sample_period)}


def run_facts(r: RigRun, plant: str, origin: int, h: float) -> dict:
    """What a rig run's record adds: the plant, the origin, when the steps were seen and the
    controller armed (s from the origin), the monitor's counts."""
    return {'plant': plant, 'origin_seq': int(origin), 'monitor_samples': r.monitor_samples,
            'arm_retries': r.arm_retries,
            'steps_s': [round((s - origin) * h, 3) for s in r.steps.detected],
            'armed_s': None if r.steps.armed_at is None else round((r.steps.armed_at - origin) * h, 3)}


def run_all(exp, rig, runs, out: Path, options, log=print) -> tuple[dict, list[dict]]:
    """Every run of an experiment on the rig, in order; ({run name: RunData}, run records)."""
    data, records = {}, []
    for i, run in enumerate(runs, 1):
        log(f'  run {i}/{len(runs)}: {run.name} -- {run.title} ({run.duration:g} s on the rig)')
        data[run.name], rec = run_one(exp, run, rig, out, options, log)
        records.append(rec)
        log(f'      done in {rec["wall_s"]:.1f} s wall')
    return data, records
