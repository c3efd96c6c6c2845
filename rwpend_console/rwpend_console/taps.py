"""Taking a fast topic at a slow pace: subscriptions that are polled, never spun.

A console that took the loop's 1 kHz ``state`` through an executor would wake for every sample
(~0.1-0.2 ms of rclpy per wake-up: 10-20 % of a core at 1 kHz, more in lockstep). A
:class:`Taps` holds its subscriptions on a node of their own that no executor spins; its thread
wakes every ``period_s`` and takes what is waiting in each subscription's queue -- with a
best-effort depth-1 queue only the newest sample, whatever the rate of the topic: DDS keeps
replacing the sample in that queue meanwhile and the console's Python never sees the others.

Taking is what rclpy's own executors do for a ready subscription
(``subscription.handle.take_message(msg_type, raw)`` under the handle's lock, rclpy 7.1.6).
Subscriptions are made, polled and destroyed on the Taps thread only.
"""
from __future__ import annotations

import concurrent.futures
import queue
import threading
import time
from typing import Callable

from rclpy.node import Node

#: seconds the thread sleeps at a time while it has nothing to poll
IDLE_WAIT_S = 0.2


class Tap:
    """One polled subscription: ``on_messages(list of (message or bytes, info))`` is called on
    the Taps thread with what was taken at a poll (at most ``limit`` messages, oldest first)."""

    def __init__(self, msg_type, topic: str, qos, on_messages: Callable[[list], None],
                 raw: bool = True, limit: int = 1) -> None:
        self.msg_type, self.topic, self.qos = msg_type, topic, qos
        self.on_messages, self.raw, self.limit = on_messages, raw, limit
        self.sub = None
        self.taken = 0
        self.polls = 0


class Taps:
    def __init__(self, context, name: str, period_s: float) -> None:
        if not 0.0005 <= period_s <= 1.0:
            raise ValueError(f'poll period must be in 0.5 ms .. 1 s, got {period_s}')
        self.period_s = period_s
        self.node = Node(name, namespace='/', context=context, start_parameter_services=False)
        self.taps: list[Tap] = []
        self._todo: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._work = threading.Event()
        self.thread = threading.Thread(target=self._run, name=f'taps-{name}', daemon=True)

    def start(self) -> None:
        self.thread.start()

    def add(self, tap: Tap) -> concurrent.futures.Future:
        """Subscribe (on the Taps thread); the future completes when it is made."""
        return self._post(lambda: self._add(tap))

    def remove(self, tap: Tap) -> concurrent.futures.Future:
        return self._post(lambda: self._remove(tap))

    def _post(self, fn) -> concurrent.futures.Future:
        fut: concurrent.futures.Future = concurrent.futures.Future()
        self._todo.put((fn, fut))
        self._work.set()
        return fut

    def _add(self, tap: Tap) -> Tap:
        tap.sub = self.node.create_subscription(tap.msg_type, tap.topic, lambda _m: None, tap.qos, raw=tap.raw)
        self.taps.append(tap)
        return tap

    def _remove(self, tap: Tap) -> None:
        if tap in self.taps:
            self.taps.remove(tap)
            self.node.destroy_subscription(tap.sub)
            tap.sub = None

    def _run(self) -> None:
        next_t = time.monotonic()
        while not self._stop.is_set():
            if not self.taps:               # nothing to poll: sleep until there is work
                self._work.wait(IDLE_WAIT_S)
                next_t = time.monotonic()
            self._work.clear()
            self._run_todo()
            for tap in list(self.taps):
                taken = self._take(tap)
                if taken:
                    tap.on_messages(taken)
            next_t = max(next_t + self.period_s, time.monotonic())
            self._stop.wait(max(0.0, next_t - time.monotonic()))

    def _run_todo(self) -> None:
        run_posted(self._todo)

    @staticmethod
    def _take(tap: Tap) -> list:
        out = []
        tap.polls += 1
        try:
            with tap.sub.handle:
                for _ in range(tap.limit):
                    got = tap.sub.handle.take_message(tap.msg_type, tap.raw)
                    if got is None:
                        break
                    out.append(got)
        except Exception:  # noqa: BLE001 - the context is shutting down: nothing to take
            return []
        tap.taken += len(out)
        return out

    def close(self) -> None:
        self._stop.set()
        if self.thread.is_alive():
            self.thread.join(timeout=2.0)
        for tap in list(self.taps):
            try:
                self._remove(tap)
            except Exception:  # noqa: BLE001 - the context may be gone
                pass
        try:
            self.node.destroy_node()
        except Exception:  # noqa: BLE001
            pass


def run_posted(todo: "queue.Queue") -> None:
    """Run every (fn, future) posted to ``todo`` on this thread, each result (or exception)
    handed to its future; returns when the queue is empty."""
    while True:
        try:
            fn, fut = todo.get_nowait()
        except queue.Empty:
            return
        if fut.set_running_or_notify_cancel():
            try:
                fut.set_result(fn())
            except Exception as exc:  # noqa: BLE001 - handed to the caller
                fut.set_exception(exc)
