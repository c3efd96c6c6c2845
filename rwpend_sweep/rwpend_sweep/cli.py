"""``./rwpend sweep SPEC.yaml --out DIR [--workers N] [--scheduler tcp://HOST:8786] [--compare A B ...]``

A robustness study: the runs of the scenario over the axes of SPEC.yaml (:mod:`rwpend_sweep.spec`),
each the loop of :mod:`rwpend_loop.loop` in lockstep (:mod:`rwpend_sweep.run`), on local worker
processes or a Dask cluster; rows to DIR/results.csv and results.parquet, the summary, plots and
DIR/index.html. An interrupted study resumes from its rows when run again with the same --out.

``--compare A B ...``: the same runs for each controller -- a gains YAML (controller parameters:
a flat mapping such as ``balance.kpp: -300`` / ``balance.design.omega0: 2wp``, or a ROS 2 params
file with a ``controller`` section), a law of one's own (``FILE.py``, the lab's ``--law``
interface: mode law), or ``default`` (the stack's controller) -- ranked by success rate, then
time to balance.

A bad spec or argument is refused with the key and the reason (exit 2) before anything runs.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import yaml

from .spec import SpecError, load_study


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        self.print_usage(sys.stderr)
        print(f'{self.prog}: error: {message}', file=sys.stderr)
        raise SystemExit(2)


def parser() -> argparse.ArgumentParser:
    import re
    from .spec import axis_names_help
    text = re.sub(r':mod:`([^`]*)`', r'\1', '\n\n'.join(__doc__.split('\n\n')[1:3])).replace('``', '')
    p = _Parser(prog='rwpend sweep', description=text, formatter_class=argparse.RawDescriptionHelpFormatter,
                epilog=f'Axis names: {axis_names_help()}.\nExample specs: rwpend_sweep/examples/. '
                       'See docs/robustness_studies.md.')
    p.add_argument('spec', help='the study (YAML: scenario, axes, samples, seed)')
    p.add_argument('--out', required=True, metavar='DIR', help='output directory (resumed if it holds this study)')
    p.add_argument('--workers', type=int, default=None, metavar='N',
                   help='local worker processes (default: the CPUs this process may use; 1: in this process)')
    p.add_argument('--scheduler', default=None, metavar='ADDRESS',
                   help='run on a Dask distributed cluster, e.g. tcp://HOST:8786 (make setup-cluster)')
    p.add_argument('--compare', nargs='+', default=None, metavar='CONTROLLER',
                   help='rank controllers: gains YAML files, law .py files, or default')
    p.add_argument('--no-page', action='store_true', help='rows and summary only (no plots, no HTML)')
    p.add_argument('--quiet', action='store_true', help='no progress line')
    return p


def load_entry(text: str):
    """A controller of --compare (SpecError with the reason)."""
    from rwpend_control.parameters import DESIGN_DEFAULTS, PARAM_FIELDS
    from rwpend_model.rig import read_params_file
    from .study import Entry
    if text == 'default':
        return Entry('default', {}, source='default')
    path = Path(text)
    if not path.is_file():
        raise SpecError(f'--compare: {text}: no such file (a gains YAML, a law .py file, or default)')
    if path.suffix == '.py':
        from rwpend_control.user_law import LawError, load_law
        from rwpend_model.rig import load_rig
        try:
            load_law(str(path.resolve()), '', load_rig())     # refused now, with the reason
        except LawError as exc:
            raise SpecError(f'--compare: {text}: {exc}') from None
        return Entry(path.stem, {}, law=(str(path.resolve()), ''), source=str(path))
    try:
        doc = yaml.safe_load(path.read_text(encoding='utf-8'))
    except (OSError, yaml.YAMLError) as exc:
        raise SpecError(f'--compare: {text}: cannot read: {exc}') from None
    if isinstance(doc, dict) and any(isinstance(v, dict) and 'ros__parameters' in v for v in doc.values()):
        try:
            flat = read_params_file(path, 'controller')
        except ValueError as exc:
            raise SpecError(f'--compare: {exc}') from None
        flat = {k: v for k, v in flat.items() if not k.startswith('rig.')}
    elif isinstance(doc, dict):
        flat = {}
        _flatten(doc, '', flat)
        flat = {k[len('controller.'):] if k.startswith('controller.') else k: v for k, v in flat.items()}
    else:
        raise SpecError(f'--compare: {text}: a mapping of controller parameters, got {type(doc).__name__}')
    unknown = sorted(k for k in flat if k not in PARAM_FIELDS and k not in DESIGN_DEFAULTS and k != 'mode')
    if unknown:
        raise SpecError(f'--compare: {text}: unknown controller parameter(s) {", ".join(unknown)}')
    flat.pop('mode', None)
    return Entry(path.stem, flat, source=str(path))


def _flatten(d: dict, prefix: str, out: dict) -> None:
    for k, v in d.items():
        if isinstance(v, dict):
            _flatten(v, f'{prefix}{k}.', out)
        else:
            out[f'{prefix}{k}'] = v


def main(argv=None) -> int:
    a = parser().parse_args(sys.argv[1:] if argv is None else list(argv))
    from .execute import cpu_count, study_fingerprint
    from .report import compare_table, summarize, summary_text, write_page
    from .study import plan, run_study
    prog = 'rwpend sweep'
    try:
        study = load_study(a.spec)
        if a.workers is not None and a.workers < 1:
            raise SpecError(f'--workers: must be >= 1, got {a.workers}')
        if a.workers is not None and a.scheduler:
            raise SpecError('--workers and --scheduler: one or the other (a cluster has its own workers)')
        if a.scheduler is not None and not (a.scheduler.startswith(('tcp://', 'tls://', 'inproc://', 'ucx://'))
                                            or ':' in a.scheduler):
            raise SpecError(f'--scheduler: an address such as tcp://HOST:8786, got {a.scheduler!r}')
        if a.scheduler is not None:
            try:
                import distributed  # noqa: F401
            except ImportError:
                raise SpecError('--scheduler needs the distributed package: make setup-cluster') from None
        entries = []
        if a.compare:
            labels = set()
            for text in a.compare:
                e = load_entry(text)
                if e.label in labels:
                    raise SpecError(f'--compare: two controllers named {e.label!r}')
                labels.add(e.label)
                entries.append(e)
        plan(study, entries)        # every run's values checked before anything runs
        doc = yaml.safe_load(Path(a.spec).read_text(encoding='utf-8'))
        fingerprint = study_fingerprint(doc, {'compare': [(e.label, e.params, e.law) for e in entries]})
        out = Path(a.out)
    except SpecError as exc:
        print(f'{prog}: error: {exc}', file=sys.stderr, flush=True)
        return 2
    workers = a.workers or cpu_count()
    print(f'{prog}: {study.name}: {study.runs * max(1, len(entries))} runs of {study.scenario.duration:g} s'
          + (f', {len(entries)} controllers' if entries else '')
          + (f' on {a.scheduler}' if a.scheduler else f' on {workers} worker(s)') + f' -> {out}',
          file=sys.stderr, flush=True)
    t0 = time.monotonic()
    try:
        rows = run_study(study, out, fingerprint, workers=workers, scheduler=a.scheduler, entries=entries,
                         stream=open('/dev/null', 'w') if a.quiet else None)
    except ValueError as exc:
        print(f'{prog}: error: {exc}', file=sys.stderr, flush=True)
        return 2
    except KeyboardInterrupt:
        print(f'\n{prog}: interrupted; run the same command again to resume from the rows in {out}',
              file=sys.stderr)
        return 130
    wall = time.monotonic() - t0
    summary = summarize(study, rows, wall_s=wall, workers=None if a.scheduler else workers)
    table = compare_table(rows) if entries else None
    if not a.no_page:
        page = write_page(study, rows, out, summary, table)
    else:
        import json
        (out / 'summary.json').write_text(json.dumps(summary, indent=2, default=str) + '\n')
        page = None
    print(summary_text(summary, table))
    print(f'written: {out / "results.csv"}' + (f', {page}' if page else ''))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
