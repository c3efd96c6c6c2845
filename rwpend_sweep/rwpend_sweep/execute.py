"""Running a study's runs: in this process, on local worker processes, or on a Dask cluster.

Every run is independent and deterministic (its setup and seeds come from the study and its
index, :mod:`rwpend_sweep.build`), so the rows do not depend on where or in what order they ran.
Rows are appended to ``DIR/partial.csv`` as they come (flushed; a task's rows at its end, its
runs stepped together: :func:`task_size`), with a progress line (runs done / failed / runs per
second / ETA); a study started again with the same ``--out`` skips the runs whose rows are there
(``study.json`` must hold the same study). At the end the rows are written in run order to
``results.csv`` and ``results.parquet``.

Engines: ``workers`` local processes (:class:`multiprocessing.pool.Pool`, fork:
the workers inherit the imported modules), ``workers == 1`` in this process, or a
``distributed.Client`` for ``--scheduler tcp://HOST:8786`` (the ``distributed`` package, an
optional extra: ``make setup-cluster``); the workers of a cluster must have the project's venv
(the same rwpend_* packages) installed.
"""
from __future__ import annotations

import csv
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Callable, Iterable

#: most runs in one task of a worker: a task's runs are stepped together, their plants one
#: numpy batch (rwpend_sweep.batch), whose cost per run falls with its size (at 500 runs about
#: 1.4 us a sample, against about 6.5 us for the plant of a run alone)
BATCH = 500
#: runs per task below which a batch costs more per run (CPU per sample of 2 s runs stepped
#: together: 500 11.5-11.9 us, 250 11.9 us, 100 13.6-13.9 us, 50 18.0 us)
BATCH_LEAST = 250


def task_size(runs: int, workers: int) -> int:
    """Runs per task: two tasks per worker, so the progress line moves and an interrupted study
    keeps more rows, but no fewer than :data:`BATCH_LEAST` runs (a worker's whole share if
    that is less) nor more than :data:`BATCH`. A task's rows come together, when it ends."""
    workers = max(1, workers)
    share = -(-runs // workers)
    return max(1, min(BATCH, max(min(BATCH_LEAST, share), -(-runs // (2 * workers)))))


class Progress:
    """The progress line: runs done / failed, runs per second, ETA (stderr; a line every 10 %
    when stderr is not a terminal)."""

    def __init__(self, total: int, already: int = 0, stream=None, label: str = '') -> None:
        self.total = total
        self.done = already
        self.failed = 0
        self.errors = 0
        self.already = already
        self.t0 = time.monotonic()
        self.stream = stream if stream is not None else sys.stderr
        self.tty = hasattr(self.stream, 'isatty') and self.stream.isatty()
        self.label = label
        self._last = 0.0
        self._tenth = -1

    def add(self, row: dict) -> None:
        self.done += 1
        if not row.get('success'):
            self.failed += 1
        if str(row.get('reason', '')).startswith('error:'):
            self.errors += 1
        self.show()

    def line(self) -> str:
        el = time.monotonic() - self.t0
        new = self.done - self.already
        rate = new / el if el > 0 else 0.0
        left = self.total - self.done
        eta = f'{left / rate:.0f} s' if rate > 0 else '?'
        width = 30
        filled = int(width * self.done / self.total) if self.total else width
        bar = '#' * filled + '.' * (width - filled)
        return (f'{self.label}[{bar}] {self.done}/{self.total} runs, {self.failed} failed'
                + (f' ({self.errors} errors)' if self.errors else '')
                + f', {rate:.1f} runs/s, ETA {eta}')

    def show(self, force: bool = False) -> None:
        now = time.monotonic()
        if self.tty:
            if force or now - self._last > 0.25 or self.done == self.total:
                self._last = now
                print('\r' + self.line(), end='\n' if self.done == self.total else '',
                      file=self.stream, flush=True)
        else:
            tenth = int(10 * self.done / self.total) if self.total else 10
            if force or tenth != self._tenth:
                self._tenth = tenth
                print(self.line(), file=self.stream, flush=True)


def chunks(items: list, n: int) -> list[list]:
    return [items[j:j + n] for j in range(0, len(items), n)]


def run_local(items: list, workers: int, on_row: Callable[[int, dict], None]) -> None:
    """Run ``items`` [(index, setup, success), ...] on ``workers`` processes (1: here)."""
    from .run import run_many
    if workers <= 1 or len(items) <= 1:
        for chunk in chunks(items, task_size(len(items), 1)):
            for i, row in run_many(chunk):
                on_row(i, row)
        return
    import multiprocessing as mp
    # the workers ignore Ctrl-C: the main process stops them (terminate) and keeps the rows
    # written so far, so an interrupted study stops at once and resumes from them
    pool = mp.get_context('fork').Pool(workers, initializer=_ignore_sigint)
    try:
        for rows in pool.imap_unordered(run_many, chunks(items, task_size(len(items), workers))):
            for i, row in rows:
                on_row(i, row)
        pool.close()
    except BaseException:
        pool.terminate()
        raise
    finally:
        pool.join()


def _ignore_sigint() -> None:
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def run_dask(items: list, scheduler, on_row: Callable[[int, dict], None]) -> None:
    """Run ``items`` on a Dask cluster: ``scheduler`` an address (tcp://HOST:8786) or a
    distributed.Client / LocalCluster."""
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise RuntimeError('--scheduler needs the distributed package: make setup-cluster') from None
    from .run import run_many
    own = isinstance(scheduler, str)
    client = Client(scheduler) if own else (scheduler if isinstance(scheduler, Client) else Client(scheduler))
    try:
        slots = sum(client.nthreads().values()) or 1
        futures = client.map(run_many, chunks(items, task_size(len(items), slots)), pure=False)
        for f in as_completed(futures):
            for i, row in f.result():
                on_row(i, row)
    finally:
        if own or not isinstance(scheduler, Client):
            client.close()


# ------------------------------------------------------------------ results on disk
def read_partial(path: Path, columns: list[str]) -> dict[int, dict]:
    """Rows already written (a torn last line of an interrupted study is dropped)."""
    out: dict[int, dict] = {}
    if not path.is_file():
        return out
    text = path.read_text(encoding='utf-8')
    if text and not text.endswith('\n'):
        text = text[:text.rfind('\n') + 1]
    lines = text.splitlines()
    if not lines:
        return out
    reader = csv.DictReader(lines)
    if reader.fieldnames != columns:
        return {}
    for rec in reader:
        try:
            out[int(rec['run'])] = {k: parse_cell(k, v) for k, v in rec.items()}
        except (KeyError, ValueError, TypeError):
            continue
    return out


def parse_cell(key: str, v: str):
    if key in ('run',):
        return int(v)
    if key == 'success':
        return v == 'True'
    if key in ('reason', 'controller'):
        return v
    try:
        return int(v) if v.lstrip('-').isdigit() else float(v)
    except ValueError:
        if v in ('True', 'False'):
            return v == 'True'
        return v


class PartialWriter:
    """Appends rows to partial.csv, flushed (an interrupted study keeps what it wrote)."""

    def __init__(self, path: Path, columns: list[str], fresh: bool) -> None:
        self.columns = columns
        new = fresh or not path.is_file() or path.stat().st_size == 0
        if not new:
            # drop a torn last line before appending
            data = path.read_bytes()
            if data and not data.endswith(b'\n'):
                path.write_bytes(data[:data.rfind(b'\n') + 1])
        self.fh = open(path, 'w' if new else 'a', newline='', encoding='utf-8')
        self.w = csv.DictWriter(self.fh, fieldnames=columns, extrasaction='ignore')
        if new:
            self.w.writeheader()
            self.fh.flush()

    def put(self, row: dict) -> None:
        self.w.writerow({k: fmt(row.get(k)) for k in self.columns})
        self.fh.flush()

    def close(self) -> None:
        self.fh.close()


def fmt(v):
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ('nan' if math.isnan(v) else repr(v))
    return v


def write_results(out: Path, rows: list[dict], columns: list[str]) -> None:
    """results.csv and results.parquet, in run order."""
    with open(out / 'results.csv', 'w', newline='', encoding='utf-8') as fh:
        w = csv.DictWriter(fh, fieldnames=columns, extrasaction='ignore')
        w.writeheader()
        for r in rows:
            w.writerow({k: fmt(r.get(k)) for k in columns})
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:       # pragma: no cover - pyarrow is in requirements.txt
        return
    cols = {}
    for c in columns:
        vals = [r.get(c) for r in rows]
        try:
            cols[c] = pa.array(vals)
        except (pa.ArrowInvalid, pa.ArrowTypeError):     # mixed kinds (a grid of text and numbers)
            cols[c] = pa.array([None if v is None else str(v) for v in vals])
    table = pa.table(cols)
    pq.write_table(table, out / 'results.parquet')


def study_fingerprint(spec_doc: dict, extra: dict) -> str:
    return json.dumps({'spec': spec_doc, **extra}, sort_keys=True, default=str)


def check_out_dir(out: Path, fingerprint: str) -> bool:
    """True when ``out`` holds this study already (resume); SpecError-like ValueError when it
    holds another."""
    f = out / 'study.json'
    if f.is_file():
        if f.read_text(encoding='utf-8') != fingerprint:
            raise ValueError(f'{out} holds another study (its study.json differs): choose a new --out '
                             'or delete it')
        return True
    if out.exists() and any(out.iterdir()):
        raise ValueError(f'{out} exists and is not a study directory: choose a new --out')
    out.mkdir(parents=True, exist_ok=True)
    f.write_text(fingerprint, encoding='utf-8')
    return False


def cpu_count() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover
        return os.cpu_count() or 1


def execute(items: list, workers: int, scheduler, on_row) -> None:
    if scheduler is not None:
        run_dask(items, scheduler, on_row)
    else:
        run_local(items, workers, on_row)


def all_rows(done: dict[int, dict], total: Iterable[int]) -> list[dict]:
    return [done[i] for i in total if i in done]
