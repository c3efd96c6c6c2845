"""The bag writer in a process of its own, for the loop's process (``rwpend_loop.host --record``).

The loop's process records the bytes its nodes publish, as rosbag2's composable recorder does.
Writing them (log-time order, ``seq`` tracking, zstd chunks: :class:`rwpend_bag.writer.BagSink`)
in a thread of that process takes the interpreter lock from the loop's thread for as long as
the loop itself runs: in lockstep, 60 s of samples at 1 kHz took 15.2 s of wall time with the
writer thread against 8.6 s with this one (PERFORMANCE.md, "What each mechanism buys"). Here the loop's
process only appends ``(topic, bytes, time)`` to a queue; a sender thread hands batches of them
to a child process through a pipe (one pickle per batch), and the child writes the bag, below a
real-time loop (:func:`_below_the_loop`). The loop's process starts the child first thing
(:func:`start_process`) and tells it the bag when its recorder is built: the child's interpreter
and imports (0.3-0.4 s) overlap the parent's, and a parent that ends before it records (a
refused parameter) leaves no bag behind.

Nothing handed over is lost:

* the child ignores SIGINT and SIGTERM (a Ctrl-C reaches the whole process group): it ends when
  told to (:meth:`ProcessBagWriter.close`), or when the pipe closes because the loop's process
  died -- then it finishes the bag with everything it got, and the report says so;
* a child that dies is reported (``writer_error`` in the report, which the parent then writes);
* when the child falls behind the pipe fills, the sender waits, and the queue grows
  (:meth:`ProcessBagWriter.queue_size`: the lockstep loop waits on it; real time keeps going).
"""
from __future__ import annotations

import collections
import json
import multiprocessing
import os
import pickle
import signal
import threading
import time
from pathlib import Path
from typing import Any, NamedTuple

from rwpend_ros.sched import RECORDER_BELOW

from .writer import BagError, BagSink, check_new_bag_path

#: seconds the child waits for a batch before closing an old chunk (BagSink.idle)
CHILD_POLL_S = 0.05
#: seconds the sender waits when nothing is queued
SEND_POLL_S = 0.002
#: messages in one pickled batch at most (pickling holds the interpreter lock: 100 messages
#: ~20 us, 4000 ~5.6 ms -- a late sample)
MAX_BATCH = 100
#: seconds to wait for the child to open the bag, and to finish it
START_TIMEOUT_S = 30.0
CLOSE_TIMEOUT_S = 120.0
#: the child's process name (/proc/PID/comm, at most 15 characters)
PROCESS_NAME = 'rwpend-bag'
DIED_WITHOUT_CLOSE = ('the recording process ended without closing the bag: the bag holds what it '
                      'handed over before it ended')


def _name_process() -> None:
    """The child's name in ``ps`` / /proc/PID/comm: :data:`PROCESS_NAME` (so a tool -- the soak
    stalling the recorder -- finds it among the loop process's children)."""
    try:
        import ctypes
        ctypes.CDLL(None, use_errno=True).prctl(15, PROCESS_NAME.encode(), 0, 0, 0)   # PR_SET_NAME
    except (OSError, AttributeError):
        pass


def _below_the_loop() -> None:
    """A real-time loop's writer runs ``RECORDER_BELOW`` SCHED_FIFO priorities below it (the
    policy it inherited from the loop's process): above every ordinary process, so a busy
    machine cannot starve it while the loop fills its queue, and below the loop, which cannot
    wait. A loop at ordinary priority (lockstep) keeps its writer at ordinary priority."""
    try:
        if os.sched_getscheduler(0) == os.SCHED_FIFO:
            prio = os.sched_getparam(0).sched_priority
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(max(1, prio - RECORDER_BELOW)))
    except (AttributeError, OSError):
        pass


def _detach() -> None:
    """Ignore SIGINT/SIGTERM (the parent says when to stop), take a name and a priority."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _name_process()
    _below_the_loop()


def serve_when_told(conn) -> None:
    """The child started ahead of its bag (:func:`start_process`): wait for ``('open', path,
    order, kwargs)``, then :func:`serve`; a pipe closed first (the parent ended before it
    recorded, e.g. on a bad parameter) ends it with nothing written."""
    _detach()
    try:
        kind, path, order, kwargs = conn.recv()
    except (EOFError, OSError):
        return
    if kind == 'open':
        serve(conn, path, order, kwargs, detach=False)


def serve(conn, path: str, order, kwargs: dict, detach: bool = True) -> None:
    """The child: open the bag, then take batches until told to stop (or the pipe closes).
    ``detach``: ignore SIGINT/SIGTERM, take a name and a priority (False: a test's thread)."""
    if detach:
        _detach()
    try:
        sink = BagSink(path, order, **kwargs)
    except BaseException as exc:  # noqa: BLE001 - told to the parent, which raises it
        conn.send(('error', f'{type(exc).__name__}: {exc}'))
        return
    conn.send(('ready', None))
    while True:
        try:
            if not conn.poll(CHILD_POLL_S):
                sink.idle()
                continue
            items = pickle.loads(conn.recv_bytes())
        except (EOFError, OSError):
            sink.finish({'writer_error': DIED_WITHOUT_CLOSE, 'writer_errors': 1})
            return
        for item in items:
            if item[0] == 'stop':
                report = sink.finish(item[1])
                conn.send(('report', report))
                return
            sink.take(item)


class WriterProcess(NamedTuple):
    """A bag writer's child process, started and not yet told its bag (:func:`start_process`)."""
    proc: Any
    conn: Any


def start_process() -> WriterProcess:
    """Start the writer's child now, its bag to come (:class:`ProcessBagWriter` ``process=``):
    its interpreter and imports (0.3-0.4 s on our slowest host) then overlap the parent's own.
    A parent that ends without recording ends the child, nothing written."""
    ctx = multiprocessing.get_context('spawn')       # never fork a process with ROS threads
    conn, child = ctx.Pipe(duplex=True)
    proc = ctx.Process(target=serve_when_told, args=(child,), name='rwpend-bag-writer')
    proc.start()
    child.close()
    return WriterProcess(proc, conn)


class ProcessBagWriter:
    """The interface of :class:`rwpend_bag.writer.ThreadedBagWriter` (``add_topic``, ``put``
    from any thread, ``queue_size``, ``close`` -> the recording report) with the writing in a
    child process (module doc). Raises :class:`BagError` when the bag cannot be opened."""

    def __init__(self, path, order=None, process: WriterProcess | None = None, **kwargs):
        """``process``: a child started ahead (:func:`start_process`), else one is started now."""
        self.path = Path(path)
        check_new_bag_path(self.path)
        started = process or start_process()
        self._conn, self._proc = started.conn, started.proc
        try:
            self._conn.send(('open', str(self.path), order, kwargs))
            if not self._conn.poll(START_TIMEOUT_S):
                self._proc.kill()
                raise BagError(f'the bag writer process did not open {self.path} within {START_TIMEOUT_S:g} s')
            kind, why = self._conn.recv()
        except (EOFError, OSError) as exc:
            self._proc.join(timeout=5.0)
            raise BagError(f'the bag writer process ended before it opened {self.path} '
                           f'({self._exit_text()}): {exc!r}') from None
        if kind != 'ready':
            self._proc.join()
            raise BagError(why)
        self._queue: collections.deque = collections.deque()
        self._sending = 0
        self.max_queue = 0
        self.error: str | None = None
        self.errors = 0
        self.lost = 0
        self._closing = threading.Event()
        self._sender = threading.Thread(target=self._send_loop, name='bag-sender', daemon=True)
        self._sender.start()

    def add_topic(self, name: str, type_name: str, qos=None) -> None:
        self._queue.append(('topic', name, type_name, qos))

    def put(self, topic: str, data: bytes, log_time_ns: int) -> None:
        self._queue.append(('msg', topic, data, log_time_ns))

    def queue_size(self) -> int:
        """Messages put and not yet handed to the child."""
        return len(self._queue) + self._sending

    def _failed(self, why: str, items: int) -> None:
        self.errors += 1
        self.lost += items
        if self.error is None:
            self.error = why

    def _send_loop(self) -> None:
        q = self._queue
        while True:
            if not q:
                if self._closing.is_set():
                    return
                time.sleep(SEND_POLL_S)
                continue
            n = len(q)
            if n > self.max_queue:
                self.max_queue = n
            items = [q.popleft() for _ in range(min(n, MAX_BATCH))]
            self._sending = len(items)
            try:
                self._conn.send_bytes(pickle.dumps(items, protocol=pickle.HIGHEST_PROTOCOL))
            except (OSError, ValueError) as exc:
                self._failed(f'the bag writer process is gone ({self._exit_text()}): {exc}',
                             sum(1 for it in items if it[0] == 'msg'))
            self._sending = 0

    def _exit_text(self) -> str:
        code = self._proc.exitcode
        return 'still running' if code is None else f'exit code {code}'

    def close(self, extra: dict[str, Any] | None = None) -> dict[str, Any]:
        """Hand over what is queued, let the child finish the bag; returns its recording report
        (or, when the child died, one that says so, also written to ``recording_report.json``)."""
        self._closing.set()
        self._sender.join()
        extra = {**(extra or {}), 'max_queue': self.max_queue}
        if self.error is None:
            try:
                self._conn.send_bytes(pickle.dumps([('stop', extra)]))
                if self._conn.poll(CLOSE_TIMEOUT_S):
                    kind, report = self._conn.recv()
                    self._proc.join()
                    return report
                self._failed(f'the bag writer process did not finish within {CLOSE_TIMEOUT_S:g} s', 0)
            except (OSError, EOFError, ValueError) as exc:
                self._failed(f'the bag writer process is gone ({self._exit_text()}): {exc}', 0)
        self._proc.join(timeout=5.0)
        if self._proc.is_alive():
            self._proc.kill()
        report = {'bag': str(self.path), 'message_count': None, 'topics': {}, **extra,
                  'writer_error': f'{self.error}; {self.lost} messages were not handed over',
                  'writer_errors': self.errors}
        try:
            (self.path / 'recording_report.json').write_text(
                json.dumps(report, indent=2, sort_keys=True) + '\n', encoding='utf-8')
        except OSError:
            pass
        return report
