"""The firmware's core as a PC-side caller uses it: through ctypes, per sample one COMMAND frame in and
one sample instant (tick_begin + tick_end), N times. Prints the mean and the distribution.

    ./rwpend exec python firmware/bench/rw_bench_ctypes.py [N]        (N = 1 000 000)
"""
import ctypes
import sys
import time

from rwpend_driver import protocol as P
from rwpend_driver.firmware import FirmwareCore
from rwpend_model.rig import load_rig


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 1_000_000
    core = FirmwareCore(load_rig())
    lib, mem = core.lib, core._mem
    out = ctypes.create_string_buffer(256)
    frame = P.pack(P.Enable(1), 0)
    lib.rw_core_receive(mem, frame, len(frame), 0, out, 256)
    # the COMMAND frames, made beforehand (the PC side's cost is not the firmware's)
    frames = [P.pack(P.Command(k, (k % 2001) - 1000), k + 1) for k in range(n)]
    each = [0.0] * n
    clock = time.perf_counter_ns
    receive, begin, end = lib.rw_core_receive, lib.rw_core_tick_begin, lib.rw_core_tick_end
    start = clock()
    for k in range(n):
        t0 = clock()
        f = frames[k]
        t_us = (k + 1) * 1000
        receive(mem, f, 14, t_us - 500, out, 256)
        begin(mem, t_us)
        end(mem, t_us, k, -k, out, 256)
        each[k] = clock() - t0
    total = clock() - start
    s = core.snapshot()
    assert s.commands == n and s.samples == n and s.enabled, (s.commands, s.samples)
    each.sort()
    print(f'ctypes: {n} samples (COMMAND frame in + tick + SAMPLE frame out): mean {total / n:.0f} ns/sample '
          f'(incl. 2 clock reads); median {each[n // 2]} ns, p99 {each[n * 99 // 100]} ns, '
          f'p99.9 {each[n * 999 // 1000]} ns, max {each[-1]} ns')


if __name__ == '__main__':
    main()
