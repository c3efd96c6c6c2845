"""A student's hand for the rig path through the emulator: ``./rwpend emulate --hand`` started on a
pty link, and a command of the stack (``lab run``, ``identify``) run with each prompt it prints
(``>>> ...``) answered by the hand's action on the emulator's stdin."""
from __future__ import annotations

import subprocess
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RWPEND = str(ROOT / 'rwpend')


def play(proc: subprocess.Popen, emu: subprocess.Popen, hand: dict, lines: list[str], hands: list[str]) -> None:
    """Read ``proc``'s output; answer each prompt that starts with a key of ``hand`` with its action
    ('' = nothing to do)."""
    for line in proc.stdout:
        lines.append(line)
        if '>>>' not in line:
            continue
        text = line.split('>>>', 1)[1].strip()
        for start, action in hand.items():
            if text.startswith(start):
                hands.append(action)
                if action:
                    emu.stdin.write(action + '\n')
                    emu.stdin.flush()
                break


def run_with_hand(tmp_path: Path, env: dict, args: list[str], hand: dict, timeout: float,
                  emulate_args: tuple = ()) -> tuple[int, list[str], list[str], Path]:
    """``./rwpend ARGS`` (``{link}`` in them replaced by the emulator's link) against the emulator;
    (exit status, output lines, hand actions taken, link)."""
    link = tmp_path / 'rig'
    lines: list[str] = []
    hands: list[str] = []
    with open(tmp_path / 'emulator.log', 'w') as emu_log:
        emu = subprocess.Popen([RWPEND, 'emulate', '--link', str(link), '--hand', '--rt-priority', '60',
                                *emulate_args], env=env, stdin=subprocess.PIPE, stdout=emu_log,
                               stderr=subprocess.STDOUT, text=True)
        try:
            end = time.monotonic() + 20
            while not link.exists() and time.monotonic() < end:
                time.sleep(0.1)
            assert link.exists(), 'the emulator did not create its link'
            proc = subprocess.Popen([RWPEND, *(a.replace('{link}', str(link)) for a in args)], env=env,
                                    stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            reader = threading.Thread(target=play, args=(proc, emu, hand, lines, hands), daemon=True)
            reader.start()
            try:
                status = proc.wait(timeout=timeout)
            finally:
                if proc.poll() is None:
                    proc.kill()
            reader.join(timeout=5)
        finally:
            emu.terminate()
            try:
                emu.wait(timeout=10)
            except subprocess.TimeoutExpired:
                emu.kill()
    return status, lines, hands, link
