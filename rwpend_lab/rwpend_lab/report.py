"""results.json and the self-contained report.html of an experiment; the course report of many.

Pure Python (html.escape, base64): figures are embedded as data URIs, so one file is the report.
"""
from __future__ import annotations

import base64
import html
import json
from pathlib import Path

from .experiment import Analysis, Experiment

CSS = """body{font-family:sans-serif;max-width:60em;margin:1em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;font-size:0.9em}td,th{border:1px solid #ccc;padding:2px 6px;text-align:left}
td.n{text-align:right;font-family:monospace}.pass{color:#060;font-weight:bold}.fail{color:#b00;font-weight:bold}
figure{margin:1em 0}figcaption{font-size:0.85em;color:#444}img{max-width:100%}.small{font-size:0.85em;color:#555}"""


def _fmt(v) -> str:
    if v is None:
        return '&mdash;'
    if isinstance(v, float):
        return f'{v:.5g}'
    return html.escape(str(v))


def results(exp: Experiment, analysis: Analysis, runs: list[dict], meta: dict) -> dict:
    """The content of results.json."""
    qs = [q.as_dict() for q in analysis.quantities]
    return {'experiment': exp.number, 'title': exp.title, 'section': exp.section,
            'figures': list(exp.figures), 'needs': list(exp.needs), **meta, 'runs': runs,
            'quantities': qs, 'passed': bool(qs) and all(q['pass'] for q in qs),
            'notes': analysis.notes, 'questions': list(exp.questions),
            'figure_files': [f'figures/{f.name}.png' for f in analysis.figures]}


def write(out: Path, exp: Experiment, analysis: Analysis, runs: list[dict], meta: dict) -> dict:
    """Write out/results.json, out/figures/*.png and out/report.html; returns the results."""
    out.mkdir(parents=True, exist_ok=True)
    (out / 'figures').mkdir(exist_ok=True)
    for f in analysis.figures:
        (out / 'figures' / f'{f.name}.png').write_bytes(f.png)
    res = results(exp, analysis, runs, meta)
    (out / 'results.json').write_text(json.dumps(res, indent=2) + '\n')
    captions = {f'figures/{f.name}.png': f.caption for f in analysis.figures}
    (out / 'report.html').write_text(page(res, out, captions))
    return res


def quantity_table(qs: list[dict]) -> str:
    rows = ['<tr><th>quantity</th><th>unit</th><th>measured</th><th>theory</th><th>tolerance</th>'
            '<th>book</th><th></th><th>reference</th></tr>']
    for q in qs:
        mark = '<span class="pass">pass</span>' if q['pass'] else '<span class="fail">FAIL</span>'
        rows.append(f'<tr><td>{html.escape(q["name"])}</td><td>{html.escape(q["unit"])}</td>'
                    f'<td class="n">{_fmt(q["measured"])}</td><td class="n">{_fmt(q["theory"])}</td>'
                    f'<td class="n">&plusmn;{_fmt(q["tolerance"])}</td><td class="n">{_fmt(q["book"])}</td>'
                    f'<td>{mark}</td><td class="small">{html.escape(q["ref"])}</td></tr>')
    return '<table>' + ''.join(rows) + '</table>'


def _img(path: Path) -> str:
    return 'data:image/png;base64,' + base64.b64encode(path.read_bytes()).decode('ascii')


def page(res: dict, out: Path, captions: dict | None = None) -> str:
    """One experiment's self-contained HTML page."""
    captions = captions or {}
    verdict = 'all quantities pass' if res['passed'] else 'some quantities FAIL'
    figs = ''.join(f'<figure><img src="{_img(out / f)}" alt="{html.escape(f)}">'
                   f'<figcaption>{html.escape(captions.get(f, f))}</figcaption></figure>'
                   for f in res['figure_files'] if (out / f).is_file())
    runs = ''.join(f'<li>{html.escape(r["name"])}: {html.escape(r["title"])} ({r["duration"]:g} s'
                   f'{", bag " + html.escape(str(r.get("bag", ""))) if r.get("bag") else ""})</li>'
                   for r in res['runs'])
    notes = ''.join(f'<li>{html.escape(n)}</li>' for n in res['notes'])
    questions = ''.join(f'<li>{html.escape(q)}</li>' for q in res['questions'])
    plant = html.escape(str(res.get('plant', 'sim')))
    return (f'<!DOCTYPE html><html><head><meta charset="utf-8"><title>Experiment {res["experiment"]}</title>'
            f'<style>{CSS}</style></head><body>'
            f'<h1>Experiment {res["experiment"]}: {html.escape(res["title"])}</h1>'
            f'<p>Section {html.escape(res["section"])} of <i>The Reaction Wheel Pendulum</i> '
            f'(Block, &Aring;str&ouml;m, Spong); book figures {", ".join(res["figures"]) or "none"}. '
            f'Plant: {plant}. <b>{verdict}</b>.</p>'
            f'<h2>Theory beside measurement</h2>{quantity_table(res["quantities"])}'
            f'<p class="small">theory: computed from the rig data ({html.escape(res.get("rig_file", "rig.yaml"))}, '
            f'g = {res.get("rig", {}).get("rig.g", "?")}); book: the value printed in the book '
            f'(computed there with g = 9.91, ERRATA E01).</p>'
            f'<h2>Runs</h2><ul>{runs}</ul><h2>Figures</h2>{figs}'
            + (f'<h2>Notes</h2><ul>{notes}</ul>' if notes else '')
            + (f'<h2>Questions for the student</h2><ol>{questions}</ol>' if questions else '')
            + '</body></html>')


def course(dirs: list[Path], out: Path) -> Path:
    """index.html (one line per experiment) + one page per experiment in ``out``; returns the index."""
    out.mkdir(parents=True, exist_ok=True)
    rows, seen = [], set()
    for d in dirs:
        f = Path(d) / 'results.json'
        if not f.is_file():
            raise FileNotFoundError(f'{d}: no results.json (not an experiment directory of ./rwpend lab run)')
        res = json.loads(f.read_text())
        name = f'exp{res["experiment"]:02d}.html'
        if name in seen:
            name = f'exp{res["experiment"]:02d}_{len(seen)}.html'
        seen.add(name)
        (out / name).write_text((Path(d) / 'report.html').read_text() if (Path(d) / 'report.html').is_file()
                                else page(res, Path(d)))
        n_pass = sum(q['pass'] for q in res['quantities'])
        mark = 'pass' if res['passed'] else 'fail'
        rows.append(f'<tr><td>{res["experiment"]}</td><td><a href="{name}">{html.escape(res["title"])}</a></td>'
                    f'<td>{html.escape(res["section"])}</td><td>{html.escape(str(res.get("plant", "sim")))}</td>'
                    f'<td class="n">{n_pass} / {len(res["quantities"])}</td>'
                    f'<td><span class="{mark}">{mark}</span></td><td class="small">{html.escape(str(d))}</td></tr>')
    index = out / 'index.html'
    index.write_text(f'<!DOCTYPE html><html><head><meta charset="utf-8"><title>The lab</title><style>{CSS}</style>'
                     f'</head><body><h1>The Reaction Wheel Pendulum: lab report</h1><table><tr><th>#</th>'
                     f'<th>experiment</th><th>section</th><th>plant</th><th>quantities passed</th><th></th>'
                     f'<th>directory</th></tr>{"".join(rows)}</table></body></html>')
    return index
