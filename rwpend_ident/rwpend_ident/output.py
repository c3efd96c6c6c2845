"""What ``./rwpend identify`` writes and prints: DIR/rig.yaml, report.html, identification.json
(or check.json for ``--check``) and the table of the identified quantities with their 95 % CIs."""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

from rwpend_model.rig import load_rig_file

from . import report
from .check import compare, format_rows
from .identify import Identification
from .models import WRITTEN
from .records import IdentError
from .rigfile import format_value, write_rig


def rig_header(ident: Identification, meta: dict) -> list[str]:
    v = ident.values
    val = ident.validation
    lines = [f'Rig parameters identified by ./rwpend identify on {time.strftime("%Y-%m-%d %H:%M")} '
             f'(plant: {meta["plant"]}; base rig: {meta["base_rig"]}).',
             'ROS 2 parameters file in the format of rwpend_model/config/rig.yaml: ./rwpend up --rig THIS_FILE.',
             'The model parameters of (2.15) are computed from these data by rwpend_model.rig, never typed in;',
             'identified (95 % confidence intervals): '
             + ', '.join(f'{k} = {v[k][0]:.6g} +- {v[k][1]:.2g}' for k in ('a', 'b_p', 'b_r', 'omega_p')) + '.',
             'm_p, j_p, j_r follow from a, b_p, b_r with g, k_u, l_p, l_r, m_r of the base rig (2.3), (2.15).']
    if val:
        lines.append(f'Validation on a held-out run: fit {val["fit_pendulum_pct"]:.1f} % (pendulum), '
                     f'{val["fit_rotor_pct"]:.1f} % (rotor). Report: report.html beside this file.')
    return lines


def rig_notes(ident: Identification) -> dict[str, str]:
    notes = {}
    for f in ident.rig.as_params():
        name = f[len('rig.'):]
        if name in WRITTEN:
            value, ci = ident.values[name]
            notes[name] = f'identified: +- {format_value(ci)} (95 %)'
        else:
            notes[name] = 'from the base rig'
    return notes


def check_written(path: Path, ident: Identification) -> None:
    """The derived a, b_p, b_r, omega_p of the file on disk agree with the fitted ones."""
    back = load_rig_file(path)
    for k in ('a', 'b_p', 'b_r', 'omega_p'):
        if not math.isclose(getattr(back, k), ident.value(k), rel_tol=1e-6):
            raise IdentError(f'{path}: {k} computed from the written file is {getattr(back, k):.8g}, '
                             f'the fit gave {ident.value(k):.8g}')


def print_table(rows: list[dict]) -> None:
    truth = 'truth' in rows[0]
    print(f'  {"quantity":30s} {"identified":>12s} {"+- 95 %":>9s} {"base (book)":>12s}'
          + (f' {"truth":>12s} {"error %":>8s} in CI' if truth else ''))
    for r in rows:
        line = f'  {r["name"]:30s} {r["value"]:12.6g} {r["ci95"]:9.2g} {r["base"]:12.6g}'
        if truth:
            line += f' {r["truth"]:12.6g} {r["error_pct"]:+8.3f} {"yes" if r["within_ci"] else "NO"}'
        print(line)


def identified(out: Path, ident: Identification, meta: dict, truth) -> int:
    path = write_rig(out / 'rig.yaml', ident.rig, rig_header(ident, meta), rig_notes(ident))
    check_written(path, ident)
    doc = report.write(out, ident, {**meta, 'rig_file': str(path)}, truth)
    print_table(doc['quantities'])
    val = ident.validation
    if val:
        print(f'  validation (held-out run): fit {val["fit_pendulum_pct"]:.1f} % pendulum, '
              f'{val["fit_rotor_pct"]:.1f} % rotor')
    print(f'rwpend identify: {path} ({meta["wall_s"]:.0f} s); use it with ./rwpend up --rig {path}\n'
          f'  report: {out / "report.html"}', flush=True)
    return 0


def check(out: Path, ident: Identification, rig, meta: dict, truth) -> int:
    rows = compare(ident, rig)
    doc = report.document(ident, meta, truth)
    doc['check'] = rows
    (out / 'check.json').write_text(json.dumps(doc, indent=2) + '\n')
    (out / 'report.html').write_text(report.page(doc, report.figures(ident), f'Check of {meta["base_rig"]}'))
    print(format_rows(rows))
    bad = [r['name'] for r in rows if not r['matches']]
    print(f'rwpend identify --check: {meta["base_rig"]} '
          + (f'DIFFERS from the rig in {", ".join(bad)}' if bad else 'still matches the rig')
          + f' ({meta["wall_s"]:.0f} s); {out / "report.html"}', flush=True)
    return 1 if bad else 0
