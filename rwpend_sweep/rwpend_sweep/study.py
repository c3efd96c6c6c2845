"""A study from its spec to its rows: prepare every run (checked), run, collect, resume.

``run_study(study, out, ...)`` -> the rows in run order. With several controllers
(``--compare``), the same runs (the same axis values and seeds) are run once per controller;
rows carry the controller's label and run = j * runs + i for the j-th controller.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .build import prepare
from .execute import PartialWriter, Progress, check_out_dir, execute, read_partial, write_results
from .run import METRICS
from .spec import Study


@dataclass(frozen=True)
class Entry:
    """A controller of a comparison: controller parameters (a gains YAML) or a law of one's own."""

    label: str
    params: dict
    law: tuple | None = None      # (source, params JSON)
    source: str = ''


def columns(study: Study, compare: bool) -> list[str]:
    return (['run'] + (['controller'] if compare else []) + [a.name for a in study.axes]
            + list(METRICS) + ['cpu_s'])


def plan(study: Study, entries: list[Entry]) -> tuple[list[dict], list]:
    """Every row's axis values and the items to run [(run, setup, success), ...], checked
    (SpecError before anything runs)."""
    base_rows, items = [], []
    n = study.runs
    for j, e in enumerate(entries or [Entry('', {})]):
        rows, setups = prepare(study, controller=e.params, law=e.law, label=e.label)
        for i, (vals, s) in enumerate(zip(rows, setups)):
            run = j * n + i
            row: dict[str, Any] = {'run': run}
            if entries:
                row['controller'] = e.label
            row.update(vals)
            base_rows.append(row)
            items.append((run, s, study.scenario.success))
    return base_rows, items


def run_study(study: Study, out: Path, fingerprint: str, *, workers: int = 1, scheduler=None,
              entries: list[Entry] | None = None, stream=None) -> list[dict]:
    """Run (or resume) the study into ``out``; returns every row in run order."""
    entries = entries or []
    base_rows, items = plan(study, entries)
    cols = columns(study, bool(entries))
    resumed = check_out_dir(out, fingerprint)
    partial = out / 'partial.csv'
    by_run = {r['run']: r for r in base_rows}
    kept = (*METRICS, 'cpu_s')
    done = {i: {**by_run[i], **{k: r[k] for k in kept}}
            for i, r in (read_partial(partial, cols) if resumed else {}).items() if i in by_run}
    todo = [it for it in items if it[0] not in done]
    progress = Progress(len(items), already=len(items) - len(todo), stream=stream)
    if resumed and done:
        progress.show(force=True)
    writer = PartialWriter(partial, cols, fresh=not done)

    def on_row(i: int, metrics: dict) -> None:
        row = {**by_run[i], **metrics}
        done[i] = row
        writer.put(row)
        progress.add(row)
    try:
        execute(todo, workers, scheduler, on_row)
    finally:
        writer.close()
    rows = [done[r['run']] for r in base_rows]
    # the values in the rows as written (a resumed row read back from the CSV equals a new one)
    write_results(out, rows, cols)
    return rows
