"""DIR/identification.json and the self-contained DIR/report.html of an identification.

Figures with the lab's helpers (matplotlib, embedded as data URIs, so one file is the report):
the data of every fitted experiment beside the identified model and the residuals, the friction
curve, the held-out validation.  No rclpy.
"""
from __future__ import annotations

import base64
import html
import json
import math

import numpy as np

from rwpend_lab.figures import finish, panels
from rwpend_lab.report import CSS

from .estimate import model_rig, record_residuals
from .identify import Identification, table
from .models import free_swing, plant_response


def _num(v):
    if isinstance(v, (float, np.floating)):
        return float(v) if math.isfinite(v) else None
    if isinstance(v, np.integer):
        return int(v)
    return v


def document(ident: Identification, meta: dict, truth=None) -> dict:
    """The content of identification.json."""
    fits = {name: {'parameters': f.as_dict(), 'residuals': f.n, 'rms_residual': f.rms, 'hac_lags': f.lags,
                   **({'per_ramp': f.extra['per_ramp']} if 'per_ramp' in f.extra else {})}
            for name, f in ident.fits.items()}
    val = {k: v for k, v in ident.validation.items() if not isinstance(v, np.ndarray)}
    rows = [{k: _num(v) for k, v in r.items()} for r in table(ident, truth)]
    return {**meta, 'rig': {k: _num(v) for k, v in ident.rig.as_params().items()}, 'quantities': rows,
            'fits': fits, 'validation': val, 'notes': ident.notes}


# ------------------------------------------------------------------ figures
def swing_figure(ident: Identification):
    f = ident.fits['swing']
    y = ident.records['swing']
    h, dl = ident.base.sample_period, ident.base.count_angle
    t = np.arange(len(y)) * h
    model = free_swing(t, f['wp2'], f['damping'], f['theta0'], f['theta_dot0']) / dl
    fig, (a1, a2) = panels(2, 2.0)
    a1.plot(t, y, lw=0.6, label='pendulum (counts)')
    a1.plot(t, model, 'k--', lw=0.5, label='model')
    a1.set_ylabel('theta (counts)')
    a1.legend(fontsize=7, loc='upper right')
    a2.plot(t, y - model, lw=0.4)
    a2.set_ylabel('residual (counts)')
    a2.set_xlabel('t (s)')
    return finish(fig, 'swing', 'Experiment 1: the free swing (rotor stuck) and the fitted model '
                  "theta'' = -omega_p'^2 sin theta - c theta' (Section 2.3); residuals below")


def records_figure(ident: Identification, key: str, caption: str):
    rig = model_rig(ident.base, ident.fits['dynamics'].x, {'wp2': ident.fits['swing']['wp2'],
                                                           'damping': ident.fits['swing']['damping'],
                                                           'breakaway': ident.value('friction_breakaway')})
    h = ident.base.sample_period
    fig, (a1, a2, a3) = panels(3, 1.9)
    for rec in ident.records[key]:
        t = np.arange(rec.n) * h
        th, phi = plant_response(rig, rec.u, rec.theta0, rec.theta_dot0)
        dl = rig.count_angle
        rp, rm = record_residuals(rig, rec)
        line = a1.plot(t, rec.mc - rec.mc[0], lw=0.8, label=rec.run if key == 'pulses' else None)[0]
        a1.plot(t, phi / dl - phi[0] / dl, 'k--', lw=0.4)
        a2.plot(t, rec.pc - rec.pc[0], lw=0.8, color=line.get_color())
        a2.plot(t, th / dl, 'k--', lw=0.4)
        a3.plot(t, rp / np.sqrt(12), lw=0.4, color=line.get_color())
    a1.set_ylabel('rotor - pendulum (counts)')
    a2.set_ylabel('pendulum (counts)')
    a3.set_ylabel('residual (counts)')
    a3.set_xlabel('t from the start of each record (s)')
    if key == 'pulses':
        a1.legend(fontsize=6, ncol=3, loc='upper right')
    return finish(fig, key, caption)


def friction_figure(ident: Identification):
    w, u, s = ident.points
    v = ident.values
    b = ident.base
    fig, (ax,) = panels(1, 3.2)
    ax.errorbar(w, u, yerr=2 * s, fmt='o', ms=3, label='PI holds: mean applied u')
    x = np.linspace(0, max(abs(w)) * 1.05, 20)
    ax.plot(x, v['friction_coulomb_pos'][0] + v['friction_viscous_pos'][0] * x, 'k-', lw=0.8, label='identified (3.17)')
    ax.plot(-x, -v['friction_coulomb_neg'][0] - v['friction_viscous_neg'][0] * x, 'k-', lw=0.8)
    ax.plot(x, b.friction_coulomb_pos + b.friction_viscous_pos * x, 'r:', lw=0.8, label='base rig (book)')
    ax.plot(-x, -b.friction_coulomb_neg - b.friction_viscous_neg * x, 'r:', lw=0.8)
    ax.set_xlabel("w = theta_r' - theta' (rad/s)")
    ax.set_ylabel('u (units)')
    ax.legend(fontsize=7, loc='upper right')
    return finish(fig, 'friction', 'Experiments 8-9: the friction curve (Fig. 3.6) from the PI speed holds, '
                  'with the fitted lines of (3.17) and those of the base rig')


def validation_figure(ident: Identification):
    v = ident.validation
    fig, axes = panels(4, 1.6)
    for ax, (y, m, label) in zip(axes[::2], ((v['pendulum'], v['pendulum_model'], 'pendulum'),
                                            (v['rotor'], v['rotor_model'], 'rotor - pendulum'))):
        ax.plot(v['t'], y, lw=0.8, label='held-out run')
        ax.plot(v['t'], m, 'k--', lw=0.5, label='identified model')
        ax.set_ylabel(f'{label} (counts)', fontsize=7)
        ax.legend(fontsize=6, loc='upper right')
    axes[1].plot(v['t'], v['pendulum'] - v['pendulum_model'], lw=0.4)
    axes[3].plot(v['t'], v['rotor'] - v['rotor_model'], lw=0.4)
    for ax in axes[1::2]:
        ax.set_ylabel('residual', fontsize=7)
    axes[-1].set_xlabel('t (s)')
    return finish(fig, 'validation', f'Validation on the held-out run: the identified model (the written rig.yaml) '
                  f'simulated with the recorded commands from rest; fit {v["fit_pendulum_pct"]:.1f} % (pendulum), '
                  f'{v["fit_rotor_pct"]:.1f} % (rotor)')


def figures(ident: Identification) -> list:
    out = [swing_figure(ident),
           records_figure(ident, 'pulses', 'Experiment 3: torque pulses and steps of the command from rest, data '
                          '(colour) and the identified model (dashed), (2.15) with (3.17), stick-slip and lag'),
           records_figure(ident, 'ramps', 'Slow torque ramps: the rotor breaks away at the static friction'),
           friction_figure(ident)]
    if ident.validation:
        out.append(validation_figure(ident))
    return out


# ------------------------------------------------------------------ page
def _fmt(v, digits: int = 5) -> str:
    if v is None:
        return '&mdash;'
    if isinstance(v, bool):
        return 'yes' if v else '<b>no</b>'
    if isinstance(v, float):
        return f'{v:.{digits}g}'
    return html.escape(str(v))


def quantity_rows(rows: list[dict]) -> str:
    truth = 'truth' in rows[0]
    head = ('<tr><th>quantity</th><th>unit</th><th>identified</th><th>&plusmn; 95 %</th><th>base rig (book)</th>'
            + ('<th>truth (simulator)</th><th>error %</th><th>truth in CI</th>' if truth else '')
            + '<th>how</th><th>reference</th></tr>')
    body = []
    for r in rows:
        extra = (f'<td class="n">{_fmt(r["truth"])}</td><td class="n">{_fmt(r["error_pct"], 3)}</td>'
                 f'<td>{_fmt(r["within_ci"])}</td>' if truth else '')
        body.append(f'<tr><td>{html.escape(r["name"])}</td><td>{html.escape(r["unit"])}</td>'
                    f'<td class="n">{_fmt(r["value"], 6)}</td><td class="n">{_fmt(r["ci95"], 2)}</td>'
                    f'<td class="n">{_fmt(r["base"])}</td>{extra}<td class="small">{html.escape(r["how"])}</td>'
                    f'<td class="small">{html.escape(r["ref"])}</td></tr>')
    return '<table>' + head + ''.join(body) + '</table>'


def page(doc: dict, figs: list, title: str = 'Identification of the rig') -> str:
    imgs = ''.join(f'<figure><img src="data:image/png;base64,{base64.b64encode(f.png).decode()}" '
                   f'alt="{html.escape(f.name)}"><figcaption>{html.escape(f.caption)}</figcaption></figure>'
                   for f in figs)
    val = doc.get('validation') or {}
    val_text = (f'<p>Held-out run: fit {val["fit_pendulum_pct"]:.1f} % (pendulum), {val["fit_rotor_pct"]:.1f} % '
                f'(rotor relative to the pendulum); rms residual {val["rms_pendulum_counts"]:.2f} / '
                f'{val["rms_rotor_counts"]:.1f} counts.</p>' if val else '')
    runs = ''.join(f'<li>{html.escape(r["name"])}: {html.escape(r["title"])}</li>' for r in doc.get('runs', []))
    notes = ''.join(f'<li>{html.escape(n)}</li>' for n in doc.get('notes', []))
    return (f'<!DOCTYPE html><html><head><meta charset="utf-8"><title>{html.escape(title)}</title>'
            f'<style>{CSS}</style></head><body><h1>{html.escape(title)}</h1>'
            f'<p>Plant: {html.escape(str(doc.get("plant")))}; base rig: {html.escape(str(doc.get("base_rig")))}; '
            f'written: {html.escape(str(doc.get("rig_file", "")))}; {doc.get("wall_s", 0):.0f} s.</p>'
            f'<h2>Identified quantities</h2>{quantity_rows(doc["quantities"])}'
            f'<h2>Validation</h2>{val_text}<h2>Figures</h2>{imgs}'
            f'<h2>Runs</h2><ul>{runs}</ul>' + (f'<h2>Notes</h2><ul>{notes}</ul>' if notes else '')
            + '</body></html>')


def write(out, ident: Identification, meta: dict, truth=None) -> dict:
    """Write out/identification.json and out/report.html; returns the document."""
    doc = document(ident, meta, truth)
    (out / 'identification.json').write_text(json.dumps(doc, indent=2) + '\n')
    (out / 'report.html').write_text(page(doc, figures(ident)))
    return doc
