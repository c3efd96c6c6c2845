"""``./rwpend identify`` -- from a new rig to its rig YAML; ``--check RIG.yaml``: does it still match?

    ./rwpend identify [--plant sim|serial:PORT] [--rig BASE.yaml] [--plant-rig TRUTH.yaml]
                      [--out DIR] [--from BAG...] [--set NODE.PARAM=VALUE ...]
    ./rwpend identify --check RIG.yaml [--plant ...] [--plant-rig ...] [--out DIR]

Runs the identification experiments through the stack (lockstep on the simulator), or re-fits the
bags of an earlier run (``--from DIR`` or ``--from BAG...``), and writes DIR/rig.yaml (load it with
``./rwpend up --rig DIR/rig.yaml``), DIR/report.html and DIR/identification.json.  The base rig
(``--rig``, default the shipped one) gives what is not identified (g, k_u, l_p, l_r, m_r, the motor
and encoder data, h) and is the rig the stack reads while identifying.  Exit status 0 when done
(``--check``: when every parameter matches), 1 when ``--check`` finds differences, 2 when the
identification is refused (the reason is printed; no rig file is written).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .records import IdentError


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog='rwpend identify', description=__doc__.split('\n\n')[0].strip('`'))
    p.add_argument('--plant', default='sim', help="sim (default) or serial:PORT (the rig, or the emulator's link)")
    p.add_argument('--rig', metavar='BASE.yaml', default=None,
                   help='the rig file to start from (default: the shipped rwpend_model/config/rig.yaml)')
    p.add_argument('--plant-rig', metavar='TRUTH.yaml', default=None,
                   help="sim: the simulated plant's truth (what the identification should find)")
    p.add_argument('--out', metavar='DIR', default=None, help='output directory (default id_out/<time>)')
    p.add_argument('--from', dest='bags', nargs='+', metavar='BAG', default=None,
                   help='re-fit recorded bags (an identification directory, or its runs/ bags) instead of running')
    p.add_argument('--check', metavar='RIG.yaml', default=None,
                   help='a short re-measurement: does the rig still match RIG.yaml, parameter by parameter?')
    p.add_argument('--set', action='append', default=[], metavar='NODE.PARAM=VALUE',
                   help='parameter override for every run, as for ./rwpend up')
    p.add_argument('--composed', nargs='?', const='loop', default=None, choices=('loop', 'control', 'none'),
                   help="the stack's layout, as ./rwpend up --composed (default: up's, the loop in one "
                   'process)')
    return p


def rigs(a):
    """(base rig, its file, the plant's truth if known) from the arguments; IdentError if bad."""
    from rwpend_model.rig import default_rig_file, load_rig_file
    base_file = Path(a.check or a.rig or default_rig_file())
    try:
        base = load_rig_file(base_file)
        truth = load_rig_file(a.plant_rig) if a.plant_rig else (base if a.plant == 'sim' and not a.bags else None)
    except (ValueError, OSError) as exc:
        raise IdentError(str(exc)) from None
    if a.plant_rig and a.plant != 'sim':
        raise IdentError('--plant-rig is the simulated plant\'s truth: it needs --plant sim')
    return base, base_file, truth


def check_inputs(a) -> None:
    """IdentError for what can be judged before anything runs (so a refused identification
    leaves nothing behind): the --set values, the bags of --from, the rig's port."""
    from rwpend_bringup.stack import parse_assignment
    for text in a.set:
        try:
            parse_assignment(text)
        except ValueError as exc:
            raise IdentError(f'--set: {exc}') from None
    if a.bags:
        from .session import bag_paths
        bag_paths(a.bags)
    elif a.plant.startswith('serial:'):
        from rwpend_lab.rigrun import port_problem
        why = port_problem(a.plant)
        if why:
            raise IdentError(why)


def out_dir(a) -> Path:
    out = Path(a.out or Path('id_out') / time.strftime('%Y%m%d_%H%M%S'))
    if out.exists() and not out.is_dir():
        raise IdentError(f'--out {out}: exists and is not a directory')
    if any((out / f).exists() for f in ('runs', 'rig.yaml', 'identification.json', 'check.json')):
        raise IdentError(f'{out} holds an identification already (choose a new --out directory)')
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise IdentError(f'--out {out}: {exc.strerror or exc}') from None
    return out


def get_data(a, runs, base, base_file: Path, out: Path, log):
    from . import session
    if a.bags:
        return session.load_bags(a.bags, runs, base), []
    if a.plant != 'sim':
        from . import rigpath
        return rigpath.run_plan(runs, base, out, a, log)
    from rwpend_lab.runner import base_stack
    opts = session.Options(stack=base_stack(a.set, a.composed, error=IdentError, rig=str(base_file),
                                            plant_rig=str(a.plant_rig) if a.plant_rig else None))
    return session.run_plan(runs, base, out, opts, log), opts.records


def main(argv=None) -> int:
    a = parser().parse_args(argv)
    t0 = time.monotonic()
    try:
        if a.plant != 'sim' and not (a.plant.startswith('serial:') and len(a.plant) > 7):
            raise IdentError(f"--plant must be 'sim' or 'serial:PORT', got {a.plant!r}")
        base, base_file, truth = rigs(a)
        check_inputs(a)
        out = out_dir(a)
        status = identify(a, base, base_file, truth, out, t0)
    except IdentError as exc:
        print(f'rwpend identify: error: {exc}', file=sys.stderr, flush=True)
        return 2
    return status


def full_bags(paths) -> bool:
    """Are these the bags of a full identification (it has a validation run)?"""
    from .session import bag_paths
    return any(b.name == 'validation' for b in bag_paths(paths))


def identify(a, base, base_file: Path, truth, out: Path, t0: float) -> int:
    from . import output
    from .identify import analyse
    from .plan import CHECK_SPEEDS, FULL_SPEEDS, plan
    # re-fitting the bags of a full identification checks with its runs (--check --from DIR)
    short = bool(a.check) and not (a.bags and full_bags(a.bags))
    from .rigpath import REST_S
    runs = plan(base, check=short, rest_timeout=3.0 if a.plant == 'sim' else REST_S)
    print(f'rwpend identify: {"checking " + str(base_file) if a.check else "identifying the rig"} on '
          f'{a.plant if not a.bags else "recorded bags"} -> {out}', flush=True)
    data, records = get_data(a, runs, base, base_file, out, lambda s: print(s, flush=True))
    ident = analyse(base, data, CHECK_SPEEDS if short else FULL_SPEEDS, [r.name for r in runs],
                    log=lambda s: print(s, flush=True))
    meta = {'plant': a.plant if not a.bags else 'bags: ' + ' '.join(a.bags), 'base_rig': str(base_file),
            'plant_rig': a.plant_rig, 'runs': records or [{'name': r.name, 'title': r.title} for r in runs],
            'wall_s': time.monotonic() - t0}
    if a.check:
        return output.check(out, ident, base, meta, truth)
    return output.identified(out, ident, meta, truth)


if __name__ == '__main__':
    sys.exit(main())
