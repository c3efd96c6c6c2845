"""``./rwpend lab list | run N | report DIR...`` -- the book's experiments, one command each."""
from __future__ import annotations

import argparse
import sys
import textwrap
import time
from pathlib import Path

from .experiment import NEEDS, LabError, Options

USAGE = """usage: rwpend lab list
       rwpend lab run N|N-M|all [--plant sim|serial:PORT] [--out DIR] [--set NODE.PARAM=VALUE ...]
                                [--law FILE.py] [--composed [loop|control|none]]
       rwpend lab template N [-o FILE]
       rwpend lab report DIR... [-o OUT]"""


def _experiments():
    from .registry import EXPERIMENTS
    return EXPERIMENTS


def list_main(argv) -> int:
    if argv:
        print('usage: rwpend lab list', file=sys.stderr)
        return 2
    for n, e in _experiments().items():
        figs = ', '.join(f'Fig. {f}' for f in e.figures) or 'no figure'
        print(f'{n:2d}  {e.title}  (Section {e.section}; {figs})')
        print(textwrap.fill('needs: ' + '; '.join(NEEDS.get(k, k) for k in e.needs)
                            + ('; --law FILE.py (template: ./rwpend lab template %d)' % n if e.template else ''),
                            width=100, initial_indent='    ', subsequent_indent='      '))
    return 0


def parse_numbers(text: str) -> list[int]:
    """'13' | '4-6' | 'all' -> experiment numbers; LabError with the reason."""
    known = list(_experiments())
    if text == 'all':
        return known
    try:
        if '-' in text:
            a, b = (int(x) for x in text.split('-', 1))
            nums = list(range(a, b + 1))
        else:
            nums = [int(text)]
    except ValueError:
        raise LabError(f'experiment must be a number 1-20, a range like 4-6, or all; got {text!r}') from None
    bad = [n for n in nums if n not in known]
    if bad or not nums:
        raise LabError(f'no experiment {bad[0] if bad else text} (the book has experiments '
                       f'{known[0]}-{known[-1]}; ./rwpend lab list)')
    return nums


def lab_rig(sets):
    """The rig the stack will run with (rig.yaml + the --set rig.* overrides); LabError if bad."""
    from rwpend_bringup.stack import parse_assignment
    from rwpend_model.rig import load_rig
    overrides = {}
    for s in sets:
        try:
            node, name, value = parse_assignment(s)
        except ValueError as exc:
            raise LabError(f'--set: {exc}') from None
        if node == 'rig':
            overrides['rig.' + name] = value
    try:
        return load_rig(overrides=overrides)
    except ValueError as exc:
        raise LabError(f'--set: {exc}') from None


def check_law(runs, law: str, rig) -> None:
    """A --law file must load, with the parameters of its runs, before anything starts (the
    controller node would refuse it at start); LabError with the reason."""
    from rwpend_control.user_law import LawError, load_law
    for r in runs:
        if r.law == law:
            try:
                load_law(law, dict(r.law_params), rig)
            except LawError as exc:
                raise LabError(f'--law: {exc}') from None


def run_one(n: int, a, log=print) -> dict:
    from . import report, runner
    exp = _experiments()[n]
    rig = lab_rig(a.set)
    options = Options(plant=a.plant, law=str(Path(a.law).resolve()) if a.law else '', sets=tuple(a.set))
    runs = exp.plan(rig, options)
    if options.law:
        check_law(runs, options.law, rig)
    out = Path(a.out) / f'exp{n:02d}' if a.many else Path(a.out)
    if (out / 'results.json').exists() or (out / 'runs').exists():
        raise LabError(f'{out} holds an experiment already (choose a new --out directory)')
    log(f'Experiment {n}: {exp.title} (Section {exp.section}) -> {out}')
    if options.rig_plant:
        from . import rigrun
        data, records = rigrun.run_all(exp, rig, runs, out, options, log=log)
    else:
        data, records = runner.run_all(exp, rig, runs, out, runner.base_stack(a.set, a.composed), log=log)
    analysis = exp.analyze(rig, data)
    meta = {'plant': a.plant, 'rig': rig.as_params(), 'options': {'law': options.law, 'set': list(a.set)}}
    res = report.write(out, exp, analysis, records, meta)
    for q in res['quantities']:
        log(f'    {"pass" if q["pass"] else "FAIL"}  {q["name"]}: measured {_g(q["measured"])}, theory '
            f'{_g(q["theory"])} +- {_g(q["tolerance"])} {q["unit"]}, book {_g(q["book"])}')
    log(f'  -> {out / "report.html"} ({"all pass" if res["passed"] else "some FAIL"})')
    return res


def _g(v) -> str:
    return f'{v:.5g}' if isinstance(v, float) else str(v)


def run_main(argv) -> int:
    p = argparse.ArgumentParser(prog='rwpend lab run', description='Run experiments of the book end to end '
                                'through the stack (lockstep on the simulator); DIR gets the bags, '
                                'results.json and report.html.')
    p.add_argument('experiment', help='number 1-20, a range like 4-6, or all')
    p.add_argument('--plant', default='sim', help="sim (default) or serial:PORT (the rig or the emulator)")
    p.add_argument('--out', default=None, help='output directory (default lab_out/expNN_<time>)')
    p.add_argument('--set', action='append', default=[], metavar='NODE.PARAM=VALUE',
                   help='parameter override for every run, as for ./rwpend up (rig.g=9.91 reproduces the '
                   "book's printed numbers)")
    p.add_argument('--law', default=None, metavar='FILE.py', help='your own law in place of the built-in one '
                   '(./rwpend lab template N writes a template)')
    p.add_argument('--composed', nargs='?', const='loop', default=None, choices=('loop', 'control', 'none'),
                   help="the stack's layout, as ./rwpend up --composed (default: up's, the loop in one "
                   'process)')
    a = p.parse_args(argv)
    t0 = time.monotonic()
    try:
        nums = parse_numbers(a.experiment)
        if a.plant != 'sim' and not (a.plant.startswith('serial:') and len(a.plant) > 7):
            raise LabError(f"--plant must be 'sim' or 'serial:PORT', got {a.plant!r}")
        if a.law:
            if len(nums) != 1:
                raise LabError('--law goes with one experiment')
            if not Path(a.law).is_file():
                raise LabError(f'--law: no such file {a.law}')
        a.many = len(nums) > 1
        if a.out is None:
            a.out = str(Path('lab_out') / (time.strftime('%Y%m%d_%H%M%S') if a.many
                                           else f'exp{nums[0]:02d}_{time.strftime("%Y%m%d_%H%M%S")}'))
        if Path(a.out).exists() and not Path(a.out).is_dir():
            raise LabError(f'--out {a.out}: exists and is not a directory')
        lab_rig(a.set)
        failed = [n for n in nums if not run_one(n, a)['passed']]
    except LabError as exc:
        print(f'rwpend lab: error: {exc}', file=sys.stderr)
        return 2
    minutes = (time.monotonic() - t0) / 60
    print(f'rwpend lab: {len(nums)} experiment(s) in {minutes:.1f} min; '
          + (f'quantities failing in {", ".join(map(str, failed))}' if failed else 'every quantity passes'))
    if a.many:
        from .report import course
        index = course(sorted(Path(a.out).glob('exp[0-9][0-9]')), Path(a.out) / 'report')
        print(f'rwpend lab: course report {index}')
    return 1 if failed else 0


def template_main(argv) -> int:
    p = argparse.ArgumentParser(prog='rwpend lab template', description='Write the --law template of an experiment.')
    p.add_argument('experiment', type=int)
    p.add_argument('-o', '--output', default=None, help='file to write (default: print it)')
    a = p.parse_args(argv)
    exp = _experiments().get(a.experiment)
    if exp is None or not exp.template:
        have = ', '.join(str(n) for n, e in _experiments().items() if e.template)
        print(f'rwpend lab: error: experiment {a.experiment} has no template (those with one: {have})',
              file=sys.stderr)
        return 2
    text = (Path(__file__).parent / 'templates' / exp.template).read_text()
    if a.output:
        Path(a.output).write_text(text)
        print(f'wrote {a.output}; run it with ./rwpend lab run {a.experiment} --law {a.output}')
    else:
        print(text, end='')
    return 0


def report_main(argv) -> int:
    p = argparse.ArgumentParser(prog='rwpend lab report', description='Gather experiment directories into '
                                'one course report (index.html + one page per experiment).')
    p.add_argument('dirs', nargs='+')
    p.add_argument('-o', '--out', default='lab_report')
    a = p.parse_args(argv)
    from .report import course
    try:
        index = course([Path(d) for d in a.dirs], Path(a.out))
    except (FileNotFoundError, ValueError, KeyError) as exc:
        print(f'rwpend lab report: error: {exc}', file=sys.stderr)
        return 2
    print(f'wrote {index}')
    return 0


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    commands = {'list': list_main, 'run': run_main, 'report': report_main, 'template': template_main}
    if not argv or argv[0] not in commands:
        print(USAGE, file=sys.stderr if argv else sys.stdout)
        return 2 if argv and argv[0] not in ('-h', '--help') else 0
    return commands[argv[0]](argv[1:])


if __name__ == '__main__':
    sys.exit(main())
