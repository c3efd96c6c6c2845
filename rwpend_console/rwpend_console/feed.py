"""The decimated samples of one rig, kept for the pages that watch it (pure; thread-safe).

The console's node adds rows as decimated samples come (:meth:`Feed.add_state`,
:meth:`Feed.add_status`); every page stream takes what is new since its cursor
(:meth:`Feed.since`), at its own pace. A page that opens late gets the last ``window_s`` of
sample time first. Rows are compact lists (the page's JSON):

* ``s``: ``[t, theta, theta_dot, wheel_rate, energy, recv_ms]`` from ``state``;
* ``u``: ``[t, u, saturated]`` from ``controller/status``: what the controller sends;
* ``a``: ``[t, u_applied]``: what the motor got -- ``u_applied`` of ``sim/true_state`` on the
  simulator, ``u`` of ``applied`` on the rig (zero while the e-stop or the command timeout holds
  the motor, whatever the controller sends);
* ``b``: ``[t, mode, law]`` whenever the mode or the law changes (never decimated away: the
  bands on the plots start there).

``t`` is the sample's stamp in seconds (sim time in lockstep, the wall clock in real time),
u and the applied command with |u| < 1e-9 as exactly 0 (:func:`rwpend_console.fmt.clean_signal`);
``recv_ms`` the console's wall clock when it took the sample (ms since the epoch): the page
measures its latency from them. Stamps that go back by more than a second start a new
``generation`` (a new run): the rows of the old one are dropped and pages start afresh.
"""
from __future__ import annotations

import threading
from collections import deque

from .decimate import RESTART_NS
from .fmt import clean_signal


class Feed:
    def __init__(self, keep_rows: int = 100_000) -> None:
        self._rows: deque = deque(maxlen=keep_rows)   # (id, kind, row)
        self._lock = threading.Lock()
        self._next_id = 1
        self.generation = 0
        self._last_ns: int | None = None
        self._last_band: tuple[str, str] | None = None

    def _stamp(self, stamp_ns: int) -> None:
        """Lock held: a stamp far behind the newest starts a new generation."""
        if self._last_ns is not None and stamp_ns < self._last_ns - RESTART_NS:
            self._rows.clear()
            self.generation += 1
            self._last_band = None
            self._last_ns = stamp_ns
        else:
            self._last_ns = stamp_ns if self._last_ns is None else max(stamp_ns, self._last_ns)

    def _add(self, kind: str, row: list) -> None:
        self._rows.append((self._next_id, kind, row))
        self._next_id += 1

    def add_state(self, stamp_ns: int, recv_ns: int, theta: float, theta_dot: float,
                  wheel_rate: float, energy: float) -> None:
        with self._lock:
            self._stamp(stamp_ns)
            self._add('s', [stamp_ns / 1e9, theta, theta_dot, wheel_rate, energy, recv_ns / 1e6])

    def add_status(self, stamp_ns: int, keep_u: bool, u: float, saturated: bool, mode: str, law: str) -> None:
        """A controller status; ``keep_u``: the decimator kept it (a change of mode or law is
        kept as a band row whatever the decimator said)."""
        with self._lock:
            self._stamp(stamp_ns)
            t = stamp_ns / 1e9
            if (mode, law) != self._last_band:
                self._last_band = (mode, law)
                self._add('b', [t, mode, law])
            if keep_u:
                self._add('u', [t, clean_signal(u), bool(saturated)])

    def add_applied(self, stamp_ns: int, u: float) -> None:
        """The command the motor was driven with over the sample stamped ``stamp_ns``."""
        with self._lock:
            self._stamp(stamp_ns)
            self._add('a', [stamp_ns / 1e9, clean_signal(u)])

    def since(self, cursor: int | None, window_s: float, generation: int | None = None) -> tuple[dict, int]:
        """Rows newer than ``cursor`` (None, or another ``generation``: the last ``window_s`` of
        sample time, with the band in force at its start) -> ({'gen', 'reset', 's', 'u', 'a', 'b'},
        new cursor)."""
        with self._lock:
            reset = cursor is None or generation != self.generation
            rows = list(self._rows) if reset else self._newer(cursor)
            new_cursor = self._rows[-1][0] if self._rows else (0 if reset else cursor)
            gen = self.generation
        out: dict = {'gen': gen, 'reset': reset, 's': [], 'u': [], 'a': [], 'b': []}
        if reset and rows:
            t_end = max(r[2][0] for r in rows)
            start = t_end - window_s
            bands_before = [r for r in rows if r[1] == 'b' and r[2][0] < start]
            rows = bands_before[-1:] + [r for r in rows if r[2][0] >= start]
        for _, kind, row in rows:
            out[kind].append(row)
        return out, new_cursor

    def _newer(self, cursor: int) -> list:
        out = []
        for item in reversed(self._rows):
            if item[0] <= cursor:
                break
            out.append(item)
        out.reverse()
        return out
