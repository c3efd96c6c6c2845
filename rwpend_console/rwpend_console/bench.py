"""The console's benchmark: does a watched console slow the loop, and how live is its page?

    ./rwpend exec python -m rwpend_console.bench [--pairs 3] [--duration 20] [--out FILE]

Interleaved pairs of real-time runs (``./rwpend up --mode auto --record``, 1 kHz, the default
layout and priority): one without the console, one with ``--console`` and its page open in
headless Chromium the whole run (the console takes the rig's topics only while a page
watches). Per run, from the bag: the share of commands the simulator saw late (its last
``/diagnostics``: ``loop_late_commands`` of the samples since the first command). Per run with
the page: its frame rate (``rwpendStats.fps``, read every second) and its latency from sample
to screen (the frame's time minus the sample's stamp, both the host's clock in real time), and
the console process's CPU. Prints a summary and writes JSON. Timing is measured here, never
asserted in a test.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

from rwpend_ros.testenv import free_port

ROOT = Path(os.environ.get('RWPEND_ROOT', Path(__file__).resolve().parents[2]))


def browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    opts = webdriver.ChromeOptions()
    opts.binary_location = shutil.which('chromium')
    for arg in ('--headless=new', '--no-sandbox', '--disable-dev-shm-usage', '--window-size=1400,1000',
                '--disable-gpu'):
        opts.add_argument(arg)
    d = webdriver.Chrome(service=Service(shutil.which('chromedriver')), options=opts)
    d.set_page_load_timeout(120)
    return d


def proc_cpu_s(pid: int) -> float:
    with open(f'/proc/{pid}/stat') as f:
        parts = f.read().rsplit(')', 1)[1].split()
    return (int(parts[11]) + int(parts[12])) / os.sysconf('SC_CLK_TCK')


def console_pid(port: int) -> int | None:
    for d in Path('/proc').iterdir():
        if d.name.isdigit():
            try:
                cmd = (d / 'cmdline').read_bytes().split(b'\0')
            except OSError:
                continue
            if b'rwpend_console.console' in cmd and str(port).encode() in cmd:
                return int(d.name)
    return None


def late_share(bag: Path) -> dict:
    """The simulator's last loop figures in the bag."""
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory
    from rwpend_bag.reader import read_bag
    t = read_bag(bag).topics['/diagnostics']
    dec = DecoderFactory().decoder_for('cdr', Schema(id=1, name=t.type, encoding='ros2msg', data=t.schema.encode()))
    last = None
    for data in t.datas:
        for s in dec(data).status:
            if s.name.endswith('/sim: plant'):
                last = {kv.key: kv.value for kv in s.values}
    if last is None:
        return {'error': 'no simulator diagnostics in the bag'}
    return {'late_commands': int(last['loop_late_commands']), 'late_percent': float(last['loop_late_percent']),
            'samples': int(last['samples'])}


def run_once(args, d, with_console: bool, workdir: Path) -> dict:
    env = dict(os.environ, ROS_DOMAIN_ID=str(args.domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    bag = workdir / f'run_{time.monotonic_ns()}'
    port = free_port()
    cmd = [str(ROOT / 'rwpend'), 'up', '--mode', 'auto', '--duration', str(args.duration), '--record', str(bag)]
    if with_console:
        cmd += ['--console', str(port)]
    log = open(workdir / f'{bag.name}.log', 'w')
    load0 = os.getloadavg()[0]
    up = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    out = {'console': with_console}
    try:
        if with_console:
            out.update(watch_page(d, port, up, workdir / f'{bag.name}.log'))
        up.wait(timeout=args.duration * 4 + 180)
    finally:
        if up.poll() is None:
            up.send_signal(signal.SIGINT)
            up.wait(timeout=60)
        log.close()
    out.update(late_share(bag))
    out['load_avg_1min'] = [round(load0, 1), round(os.getloadavg()[0], 1)]
    return out


def watch_page(d, port: int, up, log: Path) -> dict:
    """Open the page as soon as the console serves it; sample its frame rate every second."""
    end = time.monotonic() + 120
    while f'127.0.0.1:{port}' not in log.read_text(errors='replace'):
        if time.monotonic() > end or up.poll() is not None:
            return {'page_error': 'the console did not start'}
        time.sleep(0.5)
    d.get(f'http://127.0.0.1:{port}/')
    pid = console_pid(port)
    cpu0, t0 = (proc_cpu_s(pid) if pid else 0.0), time.monotonic()
    fps = []
    while up.poll() is None:
        time.sleep(1.0)
        try:
            fps.append(d.execute_script('return rwpendStats.fps;'))
            lat = d.execute_script('return rwpendStats.latency_ms.slice();')
            kind = d.execute_script('return rwpendStats.latency_kind;')
            samples = d.execute_script('return rwpendStats.samples;')
            cpu1, t1 = (proc_cpu_s(pid) if pid else 0.0), time.monotonic()
        except Exception:  # noqa: BLE001 - the stack (and the console) stopped under the page
            break
    d.get('about:blank')
    fps = sorted(f for f in fps[3:] if f)      # after the page's first seconds
    lat = sorted(lat or [])
    return {'fps_median': fps[len(fps) // 2] if fps else None, 'fps_min': fps[0] if fps else None,
            'latency_ms_p50': round(lat[len(lat) // 2], 1) if lat else None,
            'latency_ms_p95': round(lat[int(len(lat) * 0.95)], 1) if lat else None,
            'latency_kind': kind if lat else None, 'page_samples': samples if fps else None,
            'console_cpu_cores': round((cpu1 - cpu0) / (t1 - t0), 3) if pid and t1 > t0 else None}


def summary(runs: list[dict]) -> str:
    lines = []
    for with_c in (False, True):
        rs = [r for r in runs if r['console'] == with_c and 'late_percent' in r]
        pct = ', '.join(f"{r['late_percent']:.3f}" for r in rs)
        lines.append(f"{'with console + page' if with_c else 'without console    '}: late % per run {pct}")
    for r in runs:
        if r['console']:
            lines.append(f"  page: {r.get('fps_median')} frames/s (min {r.get('fps_min')}), latency p50 "
                         f"{r.get('latency_ms_p50')} ms, p95 {r.get('latency_ms_p95')} ms ({r.get('latency_kind')}), "
                         f"console {r.get('console_cpu_cores')} cores, load {r['load_avg_1min']}")
    return '\n'.join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog='python -m rwpend_console.bench', description=__doc__.split('\n\n')[0])
    p.add_argument('--pairs', type=int, default=3)
    p.add_argument('--duration', type=float, default=20.0)
    p.add_argument('--domain', type=int, default=None, help='ROS domain (default: one of RWPEND_TEST_DOMAINS)')
    p.add_argument('--out', type=Path, default=ROOT / 'console_out' / 'bench.json')
    a = p.parse_args(argv)
    if a.domain is None:
        from rwpend_ros.testenv import test_domain_id
        a.domain = test_domain_id()
    d = browser()
    runs = []
    try:
        with tempfile.TemporaryDirectory(prefix='rwpend_console_bench_') as tmp:
            for i in range(a.pairs):
                for with_console in ((False, True) if i % 2 == 0 else (True, False)):
                    r = run_once(a, d, with_console, Path(tmp))
                    runs.append(r)
                    print(json.dumps(r), flush=True)
    finally:
        d.quit()
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps({'runs': runs, 'cpus': os.cpu_count(), 'duration_s': a.duration}, indent=2) + '\n')
    print(summary(runs))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
