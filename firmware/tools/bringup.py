"""Bring-up of a rig with the reference firmware, before the stack: what the board says, its encoder
counts live, and one torque pulse to check the motor's sign (firmware/README.md, "Bring-up").

    ./rwpend exec python firmware/tools/bringup.py PORT                  # HELLO_REPLY, then counts (Ctrl-C)
    ./rwpend exec python firmware/tools/bringup.py PORT --pulse 3        # u = +3 for 0.15 s, then the verdict

The pulse is judged as ``./rwpend identify`` judges its first pulse (rwpend_ident.checks.
direction_problem, the largest moves within 0.3 s): the rotor must turn with u and the pendulum
against it. The amplifier is on only for the pulse (ENABLE 1, COMMANDs answering each SAMPLE, then
u = 0 and ENABLE 0; the device's watchdog, 50 ms, stops the motor if this program dies meanwhile).
"""
from __future__ import annotations

import argparse
import math
import sys
import time

from rwpend_driver import protocol as P
from rwpend_driver.port import serial_opener


class Board:
    def __init__(self, port: str, baud: int) -> None:
        self.port = serial_opener(port, baud)
        self.parser = P.StreamParser()
        self.seq = 0

    def send(self, msg) -> int:
        s, self.seq = self.seq, (self.seq + 1) & 0xFFFF
        self.port.write(P.pack(msg, s))
        return s

    def frames(self, timeout: float = 0.05) -> list[P.Frame]:
        return self.parser.feed(self.port.read()) if self.port.wait(timeout) else []

    def wait_for(self, pred, timeout: float, resend=None):
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for f in self.frames():
                if pred(f):
                    return f
            if resend is not None:
                resend()
        return None

    def request(self, msg) -> int:
        s = self.send(msg)
        f = self.wait_for(lambda f: f.type == P.ACK and f.msg.request_seq == s, 0.5)
        if f is None:
            raise SystemExit(f'bringup: no ACK to {msg}')
        return f.msg.result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('port')
    ap.add_argument('--baud', type=int, default=921600)
    ap.add_argument('--pulse', type=float, default=None, metavar='U',
                    help='one torque pulse of u = U (control units, |U| <= 6) for --seconds, then the verdict')
    ap.add_argument('--seconds', type=float, default=0.15)
    ap.add_argument('--duration', type=float, default=0.0, help='stop showing counts after S s (0: Ctrl-C)')
    a = ap.parse_args(argv)
    if a.pulse is not None and not (0 < abs(a.pulse) <= 6 and 0 < a.seconds <= 0.5):
        ap.error('--pulse U with 0 < |U| <= 6 and 0 < --seconds <= 0.5')
    b = Board(a.port, a.baud)
    b.port.flush_input()
    hello = b.wait_for(lambda f: f.type == P.HELLO_REPLY, 1.0, resend=lambda: b.send(P.Hello(1, 0)))
    if hello is None:
        print(f'bringup: no HELLO_REPLY on {a.port}: wiring (TX -> RX, RX <- TX, GND), baud, power?')
        return 1
    h = hello.msg
    print(f'firmware {h.fw_major}.{h.fw_minor}.{h.fw_patch}, protocol {h.proto_major}.{h.proto_minor}, '
          f'{h.counts_per_rev_pendulum}/{h.counts_per_rev_motor} counts/rev, h = {h.sample_period_us} us, '
          f'u_max = {h.u_max_milli / 1000:g}, watchdog {h.watchdog_ms} ms, serial {h.serial:#010x}')
    b.request(P.Enable(0))
    if a.pulse is None:
        print('turn the pendulum, then the wheel, by hand (Ctrl-C to stop):')
        end = time.monotonic() + a.duration if a.duration else math.inf
        last = 0.0
        try:
            while time.monotonic() < end:
                for f in b.frames():
                    if f.type == P.SAMPLE and time.monotonic() - last > 0.2:
                        s = f.msg
                        last = time.monotonic()
                        print(f'  sample {s.sample:>9}  pendulum {s.pendulum_counts:>8}  motor {s.motor_counts:>8}'
                              f'  status {",".join(P.status_names(s.status)) or "-":<24} rx_bad {s.rx_bad}', flush=True)
        except KeyboardInterrupt:
            pass
        return 0
    from rwpend_ident.checks import direction_problem
    b.request(P.SetWatchdog(50))
    first = b.wait_for(lambda f: f.type == P.SAMPLE, 0.5).msg
    b.request(P.Enable(1))
    p0, m0 = first.pendulum_counts, first.motor_counts
    dp = dm = 0
    # judged as identify judges its first pulse: the largest moves within 0.3 s of its start
    window = int(round(0.3e6 / h.sample_period_us))
    pulse = int(round(a.seconds * 1e6 / h.sample_period_us))
    milli = P.u_to_milli(a.pulse)
    n = 0
    end = time.monotonic() + 5.0
    while n < window and time.monotonic() < end:
        for f in b.frames(0.01):
            if f.type != P.SAMPLE:
                continue
            s = f.msg
            n += 1
            b.send(P.Command(s.sample, milli if n <= pulse else 0))
            if abs(s.pendulum_counts - p0) > abs(dp):
                dp = s.pendulum_counts - p0
            if abs(s.motor_counts - m0) > abs(dm):
                dm = s.motor_counts - m0
    b.send(P.Command(0, 0))
    b.request(P.Enable(0))
    count = 2 * math.pi / h.counts_per_rev_pendulum
    print(f'pulse u = {a.pulse:g} for {a.seconds:g} s: pendulum moved {dp:+d} counts, rotor {dm:+d} counts')
    why = direction_problem(a.pulse, dp * count, dm * count, count)
    print('directions: ok (the rotor turns with u, the pendulum against it)' if why is None else f'directions: {why}')
    return 0 if why is None else 2


if __name__ == '__main__':
    sys.exit(main())
