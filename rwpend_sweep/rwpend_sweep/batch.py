"""Many runs of a study at once: their plants stepped together in numpy, each run's loop its own.

A run of :mod:`rwpend_sweep.run` is the loop of :mod:`rwpend_loop.loop` around the simulated
rig; about 40 % of its time is the plant's RK4 (5 sub-steps a sample at h = 1 ms, each with four
derivatives (2.15)). Here the plants of the runs of one worker's chunk that share the sample
period are one :class:`BatchPlant` -- one numpy array per state variable and per constant, an
element per run -- integrated by the model's own functions (:func:`rwpend_model.plant.free_substep`,
:func:`~rwpend_model.plant.free_derivative`, :func:`~rwpend_model.plant.stuck_substep` ...)
with ``numpy.sin`` and ``numpy.where``: the equations are written once, in rwpend_model, for
floats and arrays alike. Each run keeps everything else as :func:`rwpend_sweep.run.build_loop`
builds it -- its :class:`SimCore` (command hold, timeout, taps and torque pulses), perturbations,
gate, estimator and controller -- and sees its plant through a :class:`Lane`, which has what
SimCore and SimHardware use of a :class:`Plant` (``step`` takes the command, the batch
integrates when every run has given its own).

Bit for bit: numpy's elementwise + - * / and comparisons are the IEEE operations of Python's
floats, numpy.sin is math.sin on this machine (a test checks both), the operations come in the
model's order, and there is no reduction: each run's samples, and so its row, are those of the
same run alone (:func:`rwpend_sweep.run.simulate`); tests compare them. A run whose plant
leaves the finite numbers (where math.sin or math.floor would raise) is run again alone, so its
row is the scalar one, error included.

``cpu_s`` of a batched run is its share of its batch's CPU time (the batch's time / its runs).
"""
from __future__ import annotations

import math
import time
from array import array

import numpy as np

from rwpend_model.plant import (Plant, PlantState, crossed_zero, free_derivative, free_substep,
                                kinetic_friction, lag_response, pwm_quantize, stick_velocity,
                                stuck_acceleration, stuck_derivative, stuck_substep,
                                torque_available)

from .metrics import metrics

#: samples of the truth kept in the batch's arrays before they go to each run's record
FLUSH = 1000

#: the constants of the model functions, one array each (an element per run)
CONSTANTS = ('_na', '_bp', '_br', '_cp', '_stuck_gain', '_wmax', '_nwmax', '_cpos', '_vpos',
             '_ncneg', '_vneg', '_decay', '_half_decay', '_fbreak', '_delta', '_umax', '_pwm_q')


class BatchPlant:
    """The plants of many runs, one sample period and the same flags (friction, back-EMF),
    stepped together: :meth:`step` is :meth:`Plant.step` of each, the sub-steps stuck or free
    per run (np.where where Plant.step branches), the same arithmetic.

    Built from the runs' :class:`Plant` objects (their constants and initial states); each is
    then seen through its :class:`Lane` (``lanes``). Attributes with the model's names hold the
    constants (arrays) for the functions of :mod:`rwpend_model.plant`."""

    def __init__(self, plants: list[Plant]) -> None:
        p0 = plants[0]
        for p in plants:
            if p.bracket or p.rotor_locked:
                raise ValueError('BatchPlant: the bracket configurations are not batched')
            if (p.h, p._n, p._dt, p.friction_on, p.back_emf) != (p0.h, p0._n, p0._dt, p0.friction_on, p0.back_emf):
                raise ValueError('BatchPlant: the plants must share the sample period and the flags')
        self.h, self._n, self._dt = p0.h, p0._n, p0._dt
        self.friction_on, self.back_emf = p0.friction_on, p0.back_emf
        self.plants = list(plants)
        for name in CONSTANTS:
            setattr(self, name, np.array([getattr(p, name) for p in plants], dtype=float))
        self._lag = np.array([p._te > 0 for p in plants])
        self.th, self.thd, self.thr, self.thrd = (np.array(v, dtype=float) for v in zip(*(p._x for p in plants)))
        self.tau = np.array([p._tau for p in plants], dtype=float)
        self.friction = np.array([p._friction for p in plants], dtype=float)
        self.stuck = np.array([p._stuck for p in plants], dtype=bool)
        self._push = np.zeros(len(plants))
        #: each run's command for the next step (set by Lane.step), and the one it held, quantized
        self.commands = [0.0] * len(plants)
        self.held = [p.u_held for p in plants]
        self.lanes = [Lane(self, i, p) for i, p in enumerate(plants)]
        self._readout()

    def __len__(self) -> int:
        return len(self.lanes)

    # ------------------------------------------------------------------ the model, on arrays
    def _free_deriv(self, th, thd, thrd, tau):
        return free_derivative(self, th, thd, thrd, tau, np.sin, np.where)[:2]

    def _stuck_acc(self, th, thd, thrd, tau):
        return stuck_acceleration(self, th, thd, np.sin)

    def _required_friction(self, th, thd, tau):
        """The friction the bearing must supply to keep each rotor stuck (Plant._required_friction)."""
        return stuck_derivative(self, th, thd, thd, tau, np.sin, np.where)[2]

    def step(self) -> np.ndarray:
        """Advance every run one sample period h with its command held (:meth:`Plant.step`
        after each run's :meth:`Lane.step`); returns which runs' states are all finite."""
        u = self._quantized()
        self._push = self._bp * np.array([ln.disturbance for ln in self.lanes], dtype=float)
        th, thd, thr, thrd = self.th, self.thd, self.thr, self.thrd
        fb, fr = self._fbreak, self.friction_on
        with np.errstate(all='ignore'):
            # with the lag the torque is continuous; without it the ZOH torque jumps to u at t_k
            tau0 = np.where(self._lag, self.tau, u)
            stuck = self.stuck
            for _ in range(self._n):
                if stuck.any():
                    # a stuck rotor breaks away when holding it needs more than the breakaway level
                    stuck = stuck & ~(np.abs(self._required_friction(th, thd, tau0)) > fb)
                some_stuck = bool(stuck.any())
                all_stuck = some_stuck and bool(stuck.all())
                if not all_stuck:
                    tau_mid, tau1 = lag_response(self, tau0, u)
                    w0 = thrd - thd
                    f_th, f_thd, f_thr, f_thrd = free_substep(self, self._free_deriv, th, thd, thr, thrd,
                                                              tau0, tau_mid, tau1)
                    sticks = None
                    if fr:
                        crossed = crossed_zero(w0, f_thrd - f_thd)
                        if some_stuck:
                            crossed &= ~stuck
                        if crossed.any():
                            # relative speed reached zero: stick if the bearing can hold the rotor
                            sticks = crossed & (np.abs(self._required_friction(f_th, f_thd, tau1)) <= fb)
                            v = stick_velocity(self._stuck_gain, f_thd, f_thrd)
                            f_thd = np.where(sticks, v, f_thd)
                            f_thrd = np.where(sticks, v, f_thrd)
                if some_stuck:
                    s_th, s_thd, s_thr, s_thrd, tau1 = stuck_substep(self, self._stuck_acc, th, thd, thr, tau0, u)
                    if all_stuck:
                        th, thd, thr, thrd = s_th, s_thd, s_thr, s_thrd
                    else:
                        th, thd = np.where(stuck, s_th, f_th), np.where(stuck, s_thd, f_thd)
                        thr, thrd = np.where(stuck, s_thr, f_thr), np.where(stuck, s_thrd, f_thrd)
                else:
                    th, thd, thr, thrd = f_th, f_thd, f_thr, f_thrd
                if not all_stuck and sticks is not None:
                    stuck = stuck | sticks
                tau0 = tau1
            self.th, self.thd, self.thr, self.thrd, self.tau, self.stuck = th, thd, thr, thrd, tau0, stuck
            kin = kinetic_friction(self, thrd - thd, np.where) if fr else 0.0
            if stuck.any():
                self.friction = np.where(stuck, self._required_friction(th, thd, tau0), kin)
            else:
                self.friction = kin if fr else np.zeros(len(self))
            finite = np.isfinite(th) & np.isfinite(thd) & np.isfinite(thr) & np.isfinite(thrd) & np.isfinite(tau0)
            if finite.all():
                self._readout()
            else:
                bad = ~finite
                for a in (self.th, self.thd, self.thr, self.thrd, self.tau):
                    a[bad] = 0.0          # dropped by the caller; keeps the readout's integers finite
                self._readout()
        return finite

    def _quantized(self) -> np.ndarray:
        """Each run's command as its amplifier realises it (:meth:`Plant.quantize_command`:
        within the limits :func:`pwm_quantize`, else the plant's own method); kept in ``held``."""
        cmd = self.commands
        u = np.array(cmd, dtype=float)
        with np.errstate(all='ignore'):
            within = (u >= -self._umax) & (u <= self._umax)
            u = np.where(within & (self._pwm_q != 0.0), pwm_quantize(self, u, np.floor), u)
        if not within.all():
            for i in np.flatnonzero(~within).tolist():
                u[i] = self.plants[i].quantize_command(cmd[i])
        self.held = u.tolist()
        return u

    def _readout(self) -> None:
        """Every run's encoder counts of the current state (:meth:`Plant.counts`), as ints;
        the rest of :meth:`Plant.readout` when asked (:meth:`rows`)."""
        th = self.th
        dl = self._delta
        self.pc = np.floor(th / dl + 0.5).astype(np.int64).tolist()
        self.mc = np.floor((self.thr - th) / dl + 0.5).astype(np.int64).tolist()
        self._rows = None

    def rows(self) -> list[tuple]:
        """Every run's :meth:`Plant.readout` of the current state, as plain Python numbers."""
        if self._rows is None:
            with np.errstate(all='ignore'):
                torque = torque_available(self, self.tau, self.thrd - self.thd, np.where)
            self._rows = list(zip(self.pc, self.mc, self.th.tolist(), self.thd.tolist(), self.thr.tolist(),
                                  self.thrd.tolist(), torque.tolist(), self.friction.tolist(),
                                  self.stuck.tolist()))
        return self._rows

    # ------------------------------------------------------------------ runs leaving the batch
    def keep(self, lanes: list) -> None:
        """Only these lanes stay (runs that ended or failed leave); they are numbered again."""
        idx = np.array([ln.i for ln in lanes], dtype=np.intp)
        for name in (*CONSTANTS, '_lag', 'th', 'thd', 'thr', 'thrd', 'tau', 'friction', 'stuck'):
            setattr(self, name, getattr(self, name)[idx])
        self.plants = [self.plants[i] for i in idx]
        self.pc = [self.pc[i] for i in idx]
        self.mc = [self.mc[i] for i in idx]
        self._rows = None
        self.held = [self.held[i] for i in idx]
        self.commands = [self.commands[i] for i in idx]
        self.lanes = list(lanes)
        for j, ln in enumerate(self.lanes):
            ln.i = j

    # ------------------------------------------------------------------ one run's state as a Plant
    def _load(self, i: int) -> Plant:
        """Run i's Plant with its current state (to apply what only a Plant does: a tap)."""
        p = self.plants[i]
        p._x = [float(self.th[i]), float(self.thd[i]), float(self.thr[i]), float(self.thrd[i])]
        p._tau, p._friction, p._stuck = float(self.tau[i]), float(self.friction[i]), bool(self.stuck[i])
        return p

    def _store(self, i: int, p: Plant) -> None:
        # new arrays: the ones of the samples before may be kept (the runs' records of the truth)
        self.th, self.thd, self.thr, self.thrd = self.th.copy(), self.thd.copy(), self.thr.copy(), self.thrd.copy()
        self.tau, self.friction, self.stuck = self.tau.copy(), self.friction.copy(), self.stuck.copy()
        self.th[i], self.thd[i], self.thr[i], self.thrd[i] = p._x
        self.tau[i], self.friction[i], self.stuck[i] = p._tau, p._friction, p._stuck
        self._readout()


class Lane:
    """One run's plant inside a :class:`BatchPlant`: what :class:`SimCore` and
    :class:`SimHardware` use of a :class:`Plant`. :meth:`step` quantizes the command as the
    plant does and hands it to the batch (the state moves at :meth:`BatchPlant.step`); the
    readout is the batch's of the current state."""

    def __init__(self, batch: BatchPlant, i: int, plant: Plant) -> None:
        self.batch = batch
        self.i = i
        self.rig = plant.rig
        self.h = plant.h
        self.t = plant.t
        self.disturbance = plant.disturbance

    def step(self, u: float = 0.0) -> None:
        """The command of the next interval (the batch quantizes it as :meth:`Plant.step`)."""
        self.batch.commands[self.i] = u
        self.t += self.h

    @property
    def u_held(self) -> float:
        """The command held over the last interval, as the amplifier realised it."""
        return self.batch.held[self.i]

    def tap(self, dv: float) -> None:
        """:meth:`Plant.tap` on this run's state."""
        b = self.batch
        p = b._load(self.i)
        p.tap(dv)
        b._store(self.i, p)

    def readout(self):
        return self.batch.rows()[self.i]

    def state_values(self):
        return self.batch.rows()[self.i][2:]

    def counts(self):
        b, i = self.batch, self.i
        return b.pc[i], b.mc[i]

    @property
    def state(self) -> PlantState:
        return PlantState(*self.state_values())


# ---------------------------------------------------------------------- runs
class _Run:
    """One run's loop and its record (what rwpend_sweep.run.simulate keeps of it)."""

    def __init__(self, index, setup, success, loop) -> None:
        self.index, self.setup, self.success, self.loop = index, setup, success, loop
        self.core = loop.hardware.core
        self.end = setup.duration - 1e-9
        self.period_ns = int(round(setup.truth.sample_period * 1e9))
        self.lane = None
        self.us = array('d')        # the command of each sample (0.0: none)
        self.sat = array('b')       # the law asked for more than u_max
        self.truth: list = []       # (theta, theta', theta_r') of each sample: arrays, in slices
        self.error = None


def run_batch(items: list) -> list[tuple[int, dict]]:
    """[(index, setup, success), ...] -> [(index, row), ...] in the same order: the runs that
    share the plant's sample period stepped together (:func:`simulate_batch`), each row that
    of :func:`rwpend_sweep.run.run_one` of the same run."""
    groups: dict = {}
    for item in items:
        groups.setdefault(item[1].truth.sample_period, []).append(item)
    rows = {}
    for group in groups.values():
        rows.update(simulate_batch(group))
    return [(i, rows[i]) for i, _, _ in items]


def simulate_batch(items: list, traces: dict | None = None) -> dict[int, dict]:
    """The rows of runs with one sample period: each run's loop built as
    :func:`rwpend_sweep.run.build_loop` builds it, its plant a lane of one BatchPlant, and
    stepped as :func:`rwpend_sweep.run.simulate` steps it, sample by sample for all at once.
    ``traces`` (a dict): each run's :class:`rwpend_sweep.run.Trace` goes there too (the truth,
    the commands and the saturation of every sample; no encoder counts)."""
    from .run import METRICS, build_loop, run_one
    t0 = time.process_time()
    rows: dict[int, dict] = {}
    runs: list[_Run] = []
    for index, setup, success in items:
        try:
            runs.append(_Run(index, setup, success, build_loop(setup, truth=False)))
        except Exception as exc:  # noqa: BLE001 - one run's error is that run's result
            rows[index] = _error_row(exc, METRICS)
    again: list = []                 # runs whose plant left the finite numbers: run alone
    if runs:
        _step_all(runs, again)
    for r in runs:
        if r.error is not None:
            rows[r.index] = _error_row(r.error, METRICS)
        elif r not in again:
            tr = _trace(r)
            rows[r.index] = metrics(tr, r.loop.controller.ctrl, r.setup, r.success)
            if traces is not None:
                traces[r.index] = tr
    share = (time.process_time() - t0) / max(1, len(items) - len(again))
    for row in rows.values():
        row['cpu_s'] = share
    for r in again:
        rows[r.index] = run_one(r.setup, r.success)
    return rows


def _step_all(runs: list[_Run], again: list) -> None:
    """Step the runs' loops sample by sample (rwpend_sweep.run.simulate's loop for each: the
    interval after the sample integrated, the end checked, the next sample), their plants one
    BatchPlant; a run that fails leaves the batch (its error kept), as does a run whose plant
    is no longer finite (appended to ``again``). The runs share the sample period."""
    batch = BatchPlant([r.core.plant for r in runs])
    for r, lane in zip(runs, batch.lanes):
        r.core.plant = r.lane = lane
    period_ns = runs[0].period_ns
    active: list[_Run] = []
    hist: list = []             # (theta, theta', theta_r') arrays of the samples not yet flushed
    finish, step, record = [], [], []
    end = 0.0                   # the earliest end of the active runs

    def regroup(still: list[_Run]) -> None:
        """Only ``still`` go on (the truth so far kept in each run's record)."""
        nonlocal active, hist, finish, step, record, end
        if active:
            _flush(active, hist)
            batch.keep([r.lane for r in still])
        active, hist = still, []
        finish = [r.loop.finish_interval for r in still]
        step = [r.loop.step for r in still]
        record = [(r.us.append, r.sat.append) for r in still]
        end = min((r.end for r in still), default=0.0)

    regroup(list(runs))
    k = 0
    while active:
        if k:
            failed = False
            for j, fin in enumerate(finish):
                try:
                    fin()                       # the plant takes the command (Lane.step)
                except Exception as exc:  # noqa: BLE001 - one run's error is that run's result
                    active[j].error = exc
                    failed = True
            if failed:
                regroup([r for r in active if r.error is None])
                if not active:
                    break
            finite = batch.step()
            if not finite.all():
                ok = finite.tolist()
                again += [r for r, o in zip(active, ok) if not o]
                regroup([r for r, o in zip(active, ok) if o])
                if not active:
                    break
        # the simulator's done(): the lanes' clocks are equal (the same h from the same t = 0)
        if active[0].lane.t >= end:
            regroup([r for r in active if r.lane.t < r.end])
            if not active:
                break
        hist.append((batch.th, batch.thd, batch.thrd))
        if len(hist) == FLUSH:
            _flush(active, hist)
            hist = []
        t = k * period_ns * 1e-9
        failed = False
        for j, (st, (us, sat)) in enumerate(zip(step, record)):
            try:
                tick = st(None, None, t)
            except Exception as exc:  # noqa: BLE001
                active[j].error = exc
                failed = True
                continue
            u = tick.u
            us(u if u is not None else 0.0)
            status = tick.status
            sat(status is not None and status.saturated)
        k += 1
        if failed:
            regroup([r for r in active if r.error is None])
    _flush(active, hist)


def _flush(runs: list[_Run], hist: list) -> None:
    """Append each run's column of the truth records ``hist`` to the run's own."""
    if not hist or not runs:
        return
    cols = [np.array([h[j] for h in hist]) for j in range(3)]
    for r in runs:
        i = r.lane.i
        r.truth.append(tuple(c[:, i] for c in cols))


def _trace(r: _Run):
    from .run import Trace
    empty = np.zeros(0, dtype=np.int64)
    th, thd, wr = (np.concatenate([seg[j] for seg in r.truth]) if r.truth else np.zeros(0) for j in range(3))
    return Trace(empty, empty, empty, np.array(r.us, dtype=float), th, thd, wr, np.array(r.sat, dtype=bool))


def _error_row(exc: Exception, metric_names) -> dict:
    row = {m: float('nan') for m in metric_names}
    row.update(success=False, reason=f'error: {type(exc).__name__}: {exc}')
    return row
