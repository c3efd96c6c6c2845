"""The rig's reference firmware (firmware/ at the top of the tree) built for this PC and bound
with ctypes: the portable C core the board runs.  The emulator (``./rwpend emulate``) runs it as
the device, and the host tests (rwpend_driver/test/test_firmware.py) compare it with the driver's
own codec and with the tests' Python statement of the device (tests/support/device.py).
"""
from __future__ import annotations

import ctypes
import fcntl
import math
import os
import shutil
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

from . import protocol as P


# ----------------------------------------------------------------------------- the firmware's core
#: the firmware's sources (firmware/ at the top of the tree) and the core built for this PC
FIRMWARE_DIR = Path(__file__).resolve().parents[2] / 'firmware'
HOST_LIBRARY = FIRMWARE_DIR / 'build' / 'host' / 'librwpend_fw.so'


class FirmwareError(RuntimeError):
    """The firmware's core cannot be built, loaded or configured (the message says why and what
    to do)."""


def _host_inputs() -> list[Path]:
    return sorted((FIRMWARE_DIR / 'core').glob('*.[ch]')) + [FIRMWARE_DIR / 'Makefile']


def _host_library_current() -> bool:
    try:
        built = HOST_LIBRARY.stat().st_mtime
        return all(f.stat().st_mtime <= built for f in _host_inputs())
    except FileNotFoundError:
        return False


def build_host_library(timeout: float = 120.0) -> Path:
    """``firmware/build/host/librwpend_fw.so``: the firmware's core built for this PC with the system
    ``cc`` (``make -C firmware host``: one compiler run, about a second), when it is missing or older
    than its sources; else nothing is run. Concurrent callers build once (a lock file). Raises
    :class:`FirmwareError` with the reason (no sources, no compiler, a compile error)."""
    if not (FIRMWARE_DIR / 'core').is_dir():
        raise FirmwareError(f'the firmware\'s sources are not there ({FIRMWARE_DIR / "core"}): the emulator '
                            'runs the firmware\'s core, built from the rwpend tree')
    if _host_library_current():
        return HOST_LIBRARY
    cc = os.environ.get('CC', 'cc')
    if shutil.which(cc) is None:
        raise FirmwareError(f'no C compiler ({cc!r} is not on PATH): the emulator runs the firmware\'s core '
                            f'(firmware/core, C99) built for this PC; install one (Debian: apt-get install gcc, '
                            f'or make setup) or set CC')
    make = shutil.which('make')
    if make is None:
        raise FirmwareError('make is not on PATH: it builds the firmware\'s core for the emulator '
                            '(Debian: apt-get install make, or make setup)')
    HOST_LIBRARY.parent.mkdir(parents=True, exist_ok=True)
    with open(HOST_LIBRARY.parent / '.build.lock', 'w') as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not _host_library_current():          # another process may have built it meanwhile
            try:
                r = subprocess.run([make, '-s', '-C', str(FIRMWARE_DIR), 'host', f'CC={cc}'],
                                   capture_output=True, text=True, timeout=timeout)
            except subprocess.TimeoutExpired as exc:
                raise FirmwareError(f'building the firmware\'s core took more than {timeout:g} s') from exc
            if r.returncode != 0 or not HOST_LIBRARY.exists():
                raise FirmwareError('building the firmware\'s core for this PC failed '
                                    f'(make -C {FIRMWARE_DIR} host):\n{(r.stdout + r.stderr).strip()}')
    return HOST_LIBRARY


class _Event(ctypes.Structure):
    """``rw_event`` (firmware/core/rw_core.h)."""
    _fields_ = [('kind', ctypes.c_uint32), ('sample', ctypes.c_uint32), ('now_us', ctypes.c_uint32),
                ('a', ctypes.c_int32), ('b', ctypes.c_int32)]


class _Drive(ctypes.Structure):
    """``rw_drive`` (firmware/core/rw_core.h): what the amplifier gets."""
    _fields_ = [('amplifier_on', ctypes.c_uint8), ('reverse', ctypes.c_uint8), ('magnitude_milli', ctypes.c_uint16)]


_EVENT_FN = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.POINTER(_Event))
_EV_ENABLE, _EV_DISABLE, _EV_WATCHDOG_TRIP, _EV_WATCHDOG_PERIOD, _EV_ZERO, _EV_HOLD_LIMIT, _EV_HOLD_EXPIRED = \
    1, 2, 3, 4, 5, 6, 7
_lib_lock = threading.Lock()
_lib: Optional[ctypes.CDLL] = None


def load_library(path: Optional[Path] = None) -> ctypes.CDLL:
    """The firmware's core for this PC (built first when needed), with its functions' C types."""
    global _lib
    with _lib_lock:
        if _lib is not None and path is None:
            return _lib
        try:
            lib = ctypes.CDLL(str(path or build_host_library()))
        except OSError as exc:
            raise FirmwareError(f'cannot load the firmware\'s core: {exc}') from exc
        vp, u8p, u32, i32, sz = ctypes.c_void_p, ctypes.c_char_p, ctypes.c_uint32, ctypes.c_int32, ctypes.c_size_t
        sigs = {
            'rw_core_size': ([], sz), 'rw_snapshot_size': ([], sz),
            'rw_snapshot_layout': ([], ctypes.c_char_p), 'rw_fw_version': ([], ctypes.c_char_p),
            'rw_config_error': ([ctypes.c_int], ctypes.c_char_p),
            'rw_config_layout': ([], ctypes.c_char_p), 'rw_config_size': ([], sz),
            'rw_core_init': ([vp, vp, _EVENT_FN, vp], ctypes.c_int),
            'rw_core_receive': ([vp, u8p, sz, u32, vp, sz], sz),
            'rw_core_tick_begin': ([vp, u32], i32),
            'rw_core_tick_end': ([vp, u32, i32, i32, vp, sz], sz),
            'rw_core_snapshot': ([vp, vp], None),
            'rw_core_drive': ([vp], _Drive),
            'rw_core_link_lost': ([vp], None),
            'rw_core_set_sample': ([vp, u32], None),
            'rw_counter_extend16': ([i32, ctypes.c_uint16], i32),
            'rw_crc16': ([u8p, sz], ctypes.c_uint16),
            'rw_frame_encode': ([vp, sz, ctypes.c_uint8, ctypes.c_uint16, u8p, ctypes.c_uint8], sz),
            'rw_payload_size': ([ctypes.c_uint8, ctypes.c_int], ctypes.c_int),
        }
        for name, (args, res) in sigs.items():
            fn = getattr(lib, name)
            fn.argtypes, fn.restype = args, res
        # rw_snapshot and rw_config as the library lays them out (one source: rw_core.h)
        for cls_name, layout, size in (('Snapshot', lib.rw_snapshot_layout, lib.rw_snapshot_size),
                                       ('Config', lib.rw_config_layout, lib.rw_config_size)):
            fields = []
            for item in layout().decode().strip(',').split(','):
                code, name = item.split()
                fields.append((name, {'u32': ctypes.c_uint32, 'i32': ctypes.c_int32}[code]))
            cls = type(cls_name, (ctypes.Structure,), {'_fields_': fields})
            if ctypes.sizeof(cls) != size():
                raise FirmwareError(f'the firmware\'s {cls_name} layout does not match its size: rebuild it '
                                    f'(make -C {FIRMWARE_DIR} host)')
            setattr(lib, cls_name, cls)
        if path is None:
            _lib = lib
        return lib


def firmware_version() -> str:
    """The firmware's version, compiled into its core (firmware/core/rw_version.h)."""
    return load_library().rw_fw_version().decode()


def _i32(v: int) -> int:
    """A count as the 32-bit hardware counter holds it (wraps)."""
    return ((v + 0x80000000) & 0xFFFFFFFF) - 0x80000000


@dataclass
class CoreCounters:
    commands: int
    ignored_commands: int
    refused: int
    watchdog_trips: int
    samples: int
    hold_expired: int = 0


class FirmwareCore:
    """The firmware's core (firmware/core/rw_core.h) through ctypes: the emulated device's logic.

    Times are the emulator's clock in seconds, given to the core as its microsecond device clock
    (wrapping at 2**32 us, as the board's). ``on_event(name, data)`` gets the core's events with the
    names and data the emulator prints: ``enable``/``disable`` (sample), ``watchdog_trip`` (t,
    since_command, sample, u_before, period), ``watchdog_period`` (period_ms), ``zero`` (mask),
    ``hold_limit`` (max_age), ``hold_expired`` (sample, age, u_before)."""

    OUT_CAP = 16384
    CHUNK = 2048           # received bytes per call: their replies always fit OUT_CAP

    def __init__(self, rig, *, watchdog_ms: int = P.DEFAULT_WATCHDOG_MS, serial: int = 0x52570001,
                 on_event: Optional[Callable[[str, dict], None]] = None, lib: Optional[ctypes.CDLL] = None) -> None:
        self.lib = lib or load_library()
        h = rig.sample_period
        values = {'counts_per_rev_pendulum': rig.counts_per_rev, 'counts_per_rev_motor': rig.counts_per_rev,
                  'sample_period_us': int(round(h * 1e6)), 'u_max_milli': int(round(rig.u_max * P.U_SCALE)),
                  'watchdog_ms': watchdog_ms, 'serial': serial,
                  # the back-EMF limit V_max / k_m in counts per sample period (OVERSPEED)
                  'overspeed_counts': int(math.floor(rig.omega_max * rig.counts_per_rev * h / (2.0 * math.pi)))}
        cfg = self.lib.Config()
        for name, _ in cfg._fields_:
            # c_uint32 would wrap a larger value silently: saturate it, the core then refuses it
            setattr(cfg, name, min(max(int(values[name]), 0), 0xFFFFFFFF))
        self._mem = ctypes.create_string_buffer(self.lib.rw_core_size())
        self.on_event = on_event
        self._now = 0.0
        self._cb = _EVENT_FN(self._event)                    # kept: C holds the pointer
        rc = self.lib.rw_core_init(self._mem, ctypes.byref(cfg), self._cb, None)
        if rc:
            raise FirmwareError(f'the emulated rig does not fit the firmware: {self.lib.rw_config_error(rc).decode()} '
                                f'(rig: h = {h:g} s, u_max = {rig.u_max:g}, counts_per_rev = {rig.counts_per_rev})')
        self.version = self.lib.rw_fw_version().decode()
        self._out = ctypes.create_string_buffer(self.OUT_CAP)

    @staticmethod
    def _us(t: float) -> int:
        return int(round(t * 1e6)) & 0xFFFFFFFF

    def _event(self, _ctx, ev_p) -> None:
        if self.on_event is None:
            return
        ev = ev_p.contents
        if ev.kind == _EV_ENABLE:
            self.on_event('enable', {'sample': ev.sample})
        elif ev.kind == _EV_DISABLE:
            self.on_event('disable', {'sample': ev.sample})
        elif ev.kind == _EV_WATCHDOG_TRIP:
            self.on_event('watchdog_trip', {'t': self._now, 'since_command': ev.a * 1e-6, 'sample': ev.sample,
                                            'u_before': ev.b / P.U_SCALE, 'period': self.watchdog_ms * 1e-3})
        elif ev.kind == _EV_WATCHDOG_PERIOD:
            self.on_event('watchdog_period', {'period_ms': ev.a})
        elif ev.kind == _EV_ZERO:
            self.on_event('zero', {'mask': ev.a})
        elif ev.kind == _EV_HOLD_LIMIT:
            self.on_event('hold_limit', {'max_age': ev.a})
        elif ev.kind == _EV_HOLD_EXPIRED:
            self.on_event('hold_expired', {'sample': ev.sample, 'age': ev.a, 'u_before': ev.b / P.U_SCALE})

    # ------------------------------------------------------------------ the HAL's calls
    def receive(self, data: bytes, now: float) -> bytes:
        """Bytes from the PC; returns the replies (HELLO_REPLY, ACK frames)."""
        self._now = now
        out = b''
        data = bytes(data)
        for i in range(0, len(data), self.CHUNK):
            chunk = data[i:i + self.CHUNK]
            n = self.lib.rw_core_receive(self._mem, chunk, len(chunk), self._us(now), self._out, self.OUT_CAP)
            out += ctypes.string_at(self._out, n)
        return out

    def tick_begin(self, now: float) -> int:
        """The sample instant: watchdog, then the command the motor gets for the period (milli-units)."""
        self._now = now
        return self.lib.rw_core_tick_begin(self._mem, self._us(now))

    def tick_end(self, now: float, pendulum_counts: int, motor_counts: int) -> bytes:
        """The encoders read: the SAMPLE frame."""
        self._now = now
        n = self.lib.rw_core_tick_end(self._mem, self._us(now), _i32(pendulum_counts), _i32(motor_counts),
                                      self._out, self.OUT_CAP)
        return ctypes.string_at(self._out, n)

    def link_lost(self) -> None:
        self.lib.rw_core_link_lost(self._mem)

    def drive(self):
        """What the amplifier gets now (amplifier_on, reverse, magnitude_milli)."""
        return self.lib.rw_core_drive(self._mem)

    # ------------------------------------------------------------------ what it shows
    def snapshot(self):
        """The core's state now (``rw_snapshot``; a new one per call: another thread may ask too)."""
        snap = self.lib.Snapshot()
        self.lib.rw_core_snapshot(self._mem, ctypes.byref(snap))
        return snap

    @property
    def k(self) -> int:
        return self.snapshot().sample

    @property
    def enabled(self) -> bool:
        return bool(self.snapshot().enabled)

    @property
    def tripped(self) -> bool:
        return bool(self.snapshot().tripped)

    @property
    def cmd_sample(self) -> int:
        return self.snapshot().cmd_sample

    @property
    def u_applied_milli(self) -> int:
        return self.snapshot().u_applied_milli

    @property
    def watchdog_ms(self) -> int:
        return self.snapshot().watchdog_ms

    @property
    def rx_bad(self) -> int:
        return self.snapshot().rx_bad

    @property
    def counters(self) -> CoreCounters:
        s = self.snapshot()
        return CoreCounters(s.commands, s.ignored_commands, s.refused, s.watchdog_trips, s.samples,
                            s.hold_expired)

    def held_command(self) -> float:
        """The command held now (control units; 0 while disabled)."""
        return self.snapshot().u_milli / P.U_SCALE

    def counts(self) -> tuple[int, int]:
        """The encoder counts at the last sample, after ZERO."""
        s = self.snapshot()
        return s.pendulum_counts, s.motor_counts

    def rx_stats(self) -> dict:
        """What the device's receiver counted (the PC side's ParserStats names)."""
        s = self.snapshot()
        return {'frames': s.rx_frames, 'bad_crc': s.rx_bad_crc, 'bad_length': s.rx_bad_length,
                'truncated': s.rx_truncated, 'unknown_type': s.rx_unknown_type,
                'garbage_bytes': s.rx_garbage_bytes, 'bytes': s.rx_bytes}
