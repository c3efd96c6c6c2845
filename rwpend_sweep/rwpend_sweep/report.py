"""A study's summary, plots and HTML page (matplotlib, Agg; no rclpy).

Plots chosen from the axes: a success map over the first two axes (a grid: the success rate of
each cell; else a scatter of the runs), with the band (6.6) |theta' + omega_p (theta - pi)| <
b_p u_max / omega_p drawn when the axes are ``initial.theta`` and ``initial.theta_dot``;
a success-rate curve over each axis (grid: per value; a distribution: per decile); histograms
of each distribution axis (succeeded / failed stacked) and of the time to balance and the
largest wheel speed. ``--compare``: the ranking table (success rate, then the median time to
balance).
"""
from __future__ import annotations

import html
import json
import math
from pathlib import Path

import numpy as np

from .spec import Study


def _col(rows: list[dict], key: str) -> np.ndarray:
    return np.array([np.nan if r.get(key) is None else r.get(key) for r in rows], dtype=float)


def _axis(rows: list[dict], key: str) -> tuple[np.ndarray, list | None]:
    """An axis's values as numbers, and the category labels when they are not numbers (text,
    booleans: plotted at 0, 1, 2 ...)."""
    vals = [r.get(key) for r in rows]
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in vals):
        return np.array(vals, dtype=float), None
    labels = list(dict.fromkeys(map(str, vals)))
    return np.array([labels.index(str(v)) for v in vals], dtype=float), labels


def _success(rows: list[dict]) -> np.ndarray:
    return np.array([bool(r.get('success')) for r in rows])


def summarize(study: Study, rows: list[dict], wall_s: float | None = None, workers: int | None = None) -> dict:
    """Counts, success rate, metric quantiles, the commonest failure reasons, speed."""
    ok = _success(rows)
    n = len(rows)
    out: dict = {'study': study.name, 'runs': n, 'succeeded': int(ok.sum()),
                 'success_rate': float(ok.mean()) if n else float('nan'),
                 'duration_s': study.scenario.duration, 'samples': study.samples, 'seed': study.seed,
                 'axes': [a.describe() for a in study.axes]}
    for m in ('time_to_balance', 'balance_rms', 'control_rms', 'saturation_share', 'max_wheel_speed'):
        v = _col(rows, m)
        v = v[np.isfinite(v)]
        out[m] = ({'median': float(np.median(v)), 'p5': float(np.percentile(v, 5)),
                   'p95': float(np.percentile(v, 95)), 'max': float(v.max())} if v.size else None)
    reasons: dict[str, int] = {}
    for r in rows:
        if not r.get('success'):
            key = _reason_kind(str(r.get('reason', '')))
            reasons[key] = reasons.get(key, 0) + 1
    out['failures'] = dict(sorted(reasons.items(), key=lambda kv: -kv[1])[:10])
    cpu = _col(rows, 'cpu_s')
    cpu = cpu[np.isfinite(cpu)]
    if cpu.size:
        out['cpu_s_per_run'] = float(cpu.mean())
        out['runs_per_s_per_core'] = float(1.0 / cpu.mean()) if cpu.mean() > 0 else None
    if wall_s is not None:
        out['wall_s'] = wall_s
        out['runs_per_s'] = n / wall_s if wall_s > 0 else None
        if workers:
            out['workers'] = workers
    band = measured_band(study, rows)
    if band:
        out['band_6_6'] = band
    return out


def _reason_kind(reason: str) -> str:
    """The reason without its numbers (for counting kinds of failure)."""
    import re
    head = reason if reason.startswith('error') else reason.split(';')[0]
    return re.sub(r'-?\d+(\.\d+)?(e-?\d+)?', '#', head).strip()


def compare_table(rows: list[dict]) -> list[dict]:
    """Rank the controllers: success rate (higher first), then the median time to balance."""
    labels = list(dict.fromkeys(r['controller'] for r in rows))
    table = []
    for lab in labels:
        rs = [r for r in rows if r['controller'] == lab]
        ok = _success(rs)
        ttb = _col(rs, 'time_to_balance')
        ttb = ttb[np.isfinite(ttb)]
        table.append({'controller': lab, 'runs': len(rs), 'success_rate': float(ok.mean()),
                      'median_time_to_balance': float(np.median(ttb)) if ttb.size else float('nan'),
                      'median_balance_rms': float(np.nanmedian(_col(rs, 'balance_rms'))),
                      'median_control_rms': float(np.nanmedian(_col(rs, 'control_rms')))})
    table.sort(key=lambda t: (-t['success_rate'], t['median_time_to_balance']
                              if math.isfinite(t['median_time_to_balance']) else math.inf))
    for k, t in enumerate(table, 1):
        t['rank'] = k
    return table


# ------------------------------------------------------------------ the band (6.6)
def band_bound(rig) -> float:
    """b_p u_max / omega_p (rad/s): the half-width of the region (6.6) in
    xi = theta' + omega_p (theta - pi) (ERRATA E41: an upper bound)."""
    return rig.b_p * rig.u_max / rig.omega_p


def measured_band(study: Study, rows: list[dict]) -> dict | None:
    """For a grid over initial.theta x initial.theta_dot: per theta column, the interval of
    theta' around the band's centre -omega_p x whose runs all succeeded, as a half-width in xi
    (the (6.6) coordinate); their median against the book's bound b_p u_max / omega_p."""
    names = [a.name for a in study.grid_axes]
    if not {'initial.theta', 'initial.theta_dot'} <= set(names):
        return None
    from .build import defaults
    rig = defaults().rig
    wp = rig.omega_p
    halfs = []
    thetas = sorted({r['initial.theta'] for r in rows})
    for th in thetas:
        col = sorted((r['initial.theta_dot'], bool(r['success'])) for r in rows if r['initial.theta'] == th)
        if len(col) < 3:
            continue
        x = math.remainder(th - math.pi, 2 * math.pi)
        centre = -wp * x
        tds = np.array([c[0] for c in col])
        ok = np.array([c[1] for c in col])
        j = int(np.argmin(np.abs(tds - centre)))
        if not ok[j]:
            continue
        lo = j
        while lo > 0 and ok[lo - 1]:
            lo -= 1
        hi = j
        while hi < len(ok) - 1 and ok[hi + 1]:
            hi += 1
        if lo == 0 or hi == len(ok) - 1:
            continue         # the successes reach the grid's edge: no width measured
        # the edge: half-way between the last success and the first failure
        up = 0.5 * (tds[hi] + tds[hi + 1]) - centre
        down = centre - 0.5 * (tds[lo] + tds[lo - 1])
        halfs.append((x, float(up), float(down)))
    if not halfs:
        return None
    widths = np.array([0.5 * (u + d) for _, u, d in halfs])
    return {'bound_rad_s': band_bound(rig), 'measured_half_width_median_rad_s': float(np.median(widths)),
            'measured_half_width_min_rad_s': float(widths.min()),
            'measured_half_width_max_rad_s': float(widths.max()), 'columns': len(halfs),
            'per_column': [{'x': x, 'up': u, 'down': d} for x, u, d in halfs]}


# ------------------------------------------------------------------ plots
def plots(study: Study, rows: list[dict], out: Path) -> list[tuple[str, str]]:
    """PNG files in ``out`` (name, caption)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    made: list[tuple[str, str]] = []
    ok = _success(rows)
    axes = list(study.axes)
    if len(axes) >= 2:
        made.append(_success_map(plt, rows, ok, axes[0], axes[1], out))
    for a in axes:
        made += _axis_plots(plt, rows, ok, a, out)
    made += _metric_histograms(plt, rows, out)
    return made


def _success_map(plt, rows: list[dict], ok: np.ndarray, a1, a2, out: Path) -> tuple[str, str]:
    """The success map over axes ``a1`` x ``a2`` (a grid: each cell's success rate; else a
    scatter of the runs; the band (6.6) over ``initial.theta`` x ``initial.theta_dot``):
    success_map.png in ``out`` (name, caption)."""
    fig, ax = plt.subplots(figsize=(7, 5.5))
    (v1, l1), (v2, l2) = _axis(rows, a1.name), _axis(rows, a2.name)
    if a1.is_grid and a2.is_grid and np.all(np.isfinite(v1)) and np.all(np.isfinite(v2)):
        xs, ys = sorted(set(v1)), sorted(set(v2))
        rate = np.full((len(ys), len(xs)), np.nan)
        for ix, xv in enumerate(xs):
            for iy, yv in enumerate(ys):
                m = (v1 == xv) & (v2 == yv)
                if m.any():
                    rate[iy, ix] = ok[m].mean()
        ext = _extent(xs, ys)
        im = ax.imshow(rate, origin='lower', aspect='auto', extent=ext, cmap='RdYlGn', vmin=0, vmax=1,
                       interpolation='nearest')
        fig.colorbar(im, ax=ax, label='success rate')
    else:
        ax.scatter(v1[~ok], v2[~ok], s=8, c='tab:red', label='failed')
        ax.scatter(v1[ok], v2[ok], s=8, c='tab:green', label='succeeded')
        ax.legend(loc='best')
    if a1.name == 'initial.theta' and a2.name == 'initial.theta_dot':
        _draw_band(ax, v1)
    if l1:
        ax.set_xticks(range(len(l1)), l1)
    if l2:
        ax.set_yticks(range(len(l2)), l2)
    ax.set_xlabel(a1.name)
    ax.set_ylabel(a2.name)
    ax.set_title(f'success over {a1.name} x {a2.name}')
    fig.tight_layout()
    fig.savefig(out / 'success_map.png', dpi=110)
    plt.close(fig)
    return ('success_map.png', f'Success over {a1.name} x {a2.name}'
            + (' with the band (6.6) of the catch' if a1.name == 'initial.theta' and
               a2.name == 'initial.theta_dot' else ''))


def _axis_plots(plt, rows: list[dict], ok: np.ndarray, a, out: Path) -> list[tuple[str, str]]:
    """The success-rate curve over axis ``a`` (a grid: per value; a distribution: per decile)
    and, for a distribution, its histogram of succeeded / failed runs: PNG files in ``out``
    (name, caption); none when the axis has no number."""
    made: list[tuple[str, str]] = []
    v, labels = _axis(rows, a.name)
    if not np.any(np.isfinite(v)):
        return made
    fig, ax = plt.subplots(figsize=(6, 3.5))
    if a.is_grid:
        xs = sorted(set(v[np.isfinite(v)]))
        ys = [ok[v == x].mean() for x in xs]
        ax.plot(xs, ys, 'o-')
        if labels:
            ax.set_xticks(range(len(labels)), labels)
    else:
        edges = np.unique(np.percentile(v, np.linspace(0, 100, 11)))
        if edges.size >= 2:
            idx = np.clip(np.digitize(v, edges[1:-1]), 0, edges.size - 2)
            mids = 0.5 * (edges[1:] + edges[:-1])
            ys = [ok[idx == k].mean() if np.any(idx == k) else np.nan for k in range(edges.size - 1)]
            ax.plot(mids, ys, 'o-')
    ax.set_ylim(-0.05, 1.05)
    ax.set_xlabel(a.name)
    ax.set_ylabel('success rate')
    ax.grid(alpha=0.3)
    fig.tight_layout()
    name = f'rate_{_safe(a.name)}.png'
    fig.savefig(out / name, dpi=100)
    plt.close(fig)
    made.append((name, f'Success rate over {a.name}' + ('' if a.is_grid else ' (per decile)')))
    if not a.is_grid:
        fig, ax = plt.subplots(figsize=(6, 3.5))
        ax.hist([v[ok], v[~ok]], bins=30, stacked=True, color=['tab:green', 'tab:red'],
                label=['succeeded', 'failed'])
        ax.set_xlabel(a.name)
        ax.set_ylabel('runs')
        ax.legend()
        fig.tight_layout()
        name = f'hist_{_safe(a.name)}.png'
        fig.savefig(out / name, dpi=100)
        plt.close(fig)
        made.append((name, f'Histogram of {a.name} ({a.dist})'))
    return made


def _metric_histograms(plt, rows: list[dict], out: Path) -> list[tuple[str, str]]:
    """Histograms of the time to balance and the largest wheel speed (where at least two runs
    have one): PNG files in ``out`` (name, caption)."""
    made: list[tuple[str, str]] = []
    for m, unit in (('time_to_balance', 's'), ('max_wheel_speed', 'rad/s')):
        v = _col(rows, m)
        v = v[np.isfinite(v)]
        if v.size < 2:
            continue
        fig, ax = plt.subplots(figsize=(6, 3.5))
        ax.hist(v, bins=30, color='tab:blue')
        ax.set_xlabel(f'{m} ({unit})')
        ax.set_ylabel('runs')
        fig.tight_layout()
        fig.savefig(out / f'hist_{m}.png', dpi=100)
        plt.close(fig)
        made.append((f'hist_{m}.png', f'Histogram of {m}'))
    return made


def _extent(xs, ys):
    def edges(v):
        if len(v) == 1:
            return v[0] - 0.5, v[0] + 0.5
        d0, d1 = v[1] - v[0], v[-1] - v[-2]
        return v[0] - d0 / 2, v[-1] + d1 / 2
    x0, x1 = edges(xs)
    y0, y1 = edges(ys)
    return (x0, x1, y0, y1)


def _draw_band(ax, thetas) -> None:
    """The band (6.6): theta' = -omega_p (theta - pi) +- b_p u_max / omega_p."""
    from .build import defaults
    rig = defaults().rig
    wp = rig.omega_p
    b = band_bound(rig)
    th = np.linspace(np.nanmin(thetas), np.nanmax(thetas), 50)
    x = th - math.pi
    for s, lab in ((1, f'(6.6): |theta\' + omega_p x| = b_p u_max / omega_p = {b:.3f} rad/s'), (-1, None)):
        ax.plot(th, -wp * x + s * b, 'k--', lw=1.5, label=lab)
    ax.plot(th, -wp * x, 'k:', lw=1, label='theta\' = -omega_p x (the centre)')
    ax.legend(loc='upper right', fontsize=8)


def _safe(name: str) -> str:
    return ''.join(ch if ch.isalnum() or ch in '_-' else '_' for ch in name)


# ------------------------------------------------------------------ the page
def write_page(study: Study, rows: list[dict], out: Path, summary: dict,
               table: list[dict] | None = None) -> Path:
    """``out/index.html``: the summary, the ranking (compare), the plots, the failures."""
    images = plots(study, rows, out)
    (out / 'summary.json').write_text(json.dumps(summary, indent=2, default=str) + '\n', encoding='utf-8')
    if table:
        (out / 'ranking.json').write_text(json.dumps(table, indent=2) + '\n', encoding='utf-8')
    e = html.escape
    parts = [f'<!doctype html><html><head><meta charset="utf-8"><title>{e(study.name)} - rwpend sweep</title>',
             '<style>body{font-family:sans-serif;max-width:1100px;margin:1em auto}table{border-collapse:collapse}'
             'td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}th{background:#eee}'
             'img{max-width:100%;border:1px solid #ddd}figure{display:inline-block;margin:6px}</style></head><body>',
             f'<h1>Robustness study: {e(study.name)}</h1>',
             f'<p>{summary["runs"]} runs of {study.scenario.duration:g} s (mode {e(study.scenario.mode)}), '
             f'{summary["succeeded"]} succeeded: <b>{100 * summary["success_rate"]:.1f} %</b>. '
             f'Success: |&theta; &minus; &pi;| &lt; {study.scenario.success.tolerance:g} rad over the last '
             f'{study.scenario.success.last:g} s'
             + (f', never beyond {study.scenario.success.never_beyond:g} rad' if study.scenario.success.never_beyond else '')
             + '.</p>',
             '<p>Axes: ' + '; '.join(e(a) for a in summary['axes']) + f'. Seed {study.seed}, {study.samples} '
             'sample(s) per grid point.</p>']
    if summary.get('wall_s') is not None:
        parts.append(f'<p>Wall time {summary["wall_s"]:.1f} s'
                     + (f' on {summary.get("workers")} worker(s)' if summary.get('workers') else '')
                     + (f', {summary["runs_per_s"]:.1f} runs/s' if summary.get('runs_per_s') else '')
                     + (f'; {summary["runs_per_s_per_core"]:.2f} runs/s per core (CPU per run '
                        f'{summary["cpu_s_per_run"]:.3f} s)' if summary.get('runs_per_s_per_core') else '')
                     + '.</p>')
    if table:
        parts.append('<h2>Ranking</h2><table><tr><th>rank</th><th>controller</th><th>runs</th><th>success rate</th>'
                     '<th>median time to balance (s)</th><th>median balance RMS (rad)</th>'
                     '<th>median control RMS</th></tr>')
        for t in table:
            parts.append(f'<tr><td>{t["rank"]}</td><td style="text-align:left">{e(t["controller"])}</td>'
                         f'<td>{t["runs"]}</td><td>{100 * t["success_rate"]:.1f} %</td>'
                         f'<td>{t["median_time_to_balance"]:.3f}</td><td>{t["median_balance_rms"]:.2e}</td>'
                         f'<td>{t["median_control_rms"]:.3f}</td></tr>')
        parts.append('</table>')
    band = summary.get('band_6_6')
    if band:
        parts.append(f'<h2>The band (6.6)</h2><p>Measured half-width of the catch basin in '
                     f'&xi; = &theta;\' + &omega;<sub>p</sub>(&theta; &minus; &pi;): median '
                     f'{band["measured_half_width_median_rad_s"]:.3f} rad/s (min {band["measured_half_width_min_rad_s"]:.3f}, '
                     f'max {band["measured_half_width_max_rad_s"]:.3f}, {band["columns"]} columns) against the '
                     f'book\'s bound b<sub>p</sub> u<sub>max</sub> / &omega;<sub>p</sub> = {band["bound_rad_s"]:.3f} rad/s.</p>')
    parts.append('<h2>Metrics</h2><table><tr><th>metric</th><th>median</th><th>p5</th><th>p95</th><th>max</th></tr>')
    for m in ('time_to_balance', 'balance_rms', 'control_rms', 'saturation_share', 'max_wheel_speed'):
        q = summary.get(m)
        if q:
            parts.append(f'<tr><td style="text-align:left">{m}</td>' + ''.join(
                f'<td>{q[k]:.4g}</td>' for k in ('median', 'p5', 'p95', 'max')) + '</tr>')
    parts.append('</table>')
    if summary.get('failures'):
        parts.append('<h2>Failures</h2><table><tr><th>reason</th><th>runs</th></tr>' + ''.join(
            f'<tr><td style="text-align:left">{e(k)}</td><td>{v}</td></tr>' for k, v in summary['failures'].items())
            + '</table>')
    parts.append('<h2>Plots</h2>')
    for name, cap in images:
        parts.append(f'<figure><img src="{e(name)}" alt="{e(cap)}"><figcaption>{e(cap)}</figcaption></figure>')
    parts.append('<p>Rows: <a href="results.csv">results.csv</a>, results.parquet; '
                 '<a href="summary.json">summary.json</a>.</p></body></html>')
    page = out / 'index.html'
    page.write_text('\n'.join(parts), encoding='utf-8')
    return page


def summary_text(summary: dict, table: list[dict] | None = None) -> str:
    lines = [f'{summary["study"]}: {summary["runs"]} runs, {summary["succeeded"]} succeeded '
             f'({100 * summary["success_rate"]:.1f} %)']
    if summary.get('wall_s') is not None:
        lines.append(f'  wall {summary["wall_s"]:.1f} s, {summary.get("runs_per_s") or 0:.1f} runs/s; '
                     f'{summary.get("runs_per_s_per_core") or 0:.2f} runs/s per core')
    t = summary.get('time_to_balance')
    if t:
        lines.append(f'  time to balance: median {t["median"]:.2f} s, p95 {t["p95"]:.2f} s')
    for k, v in (summary.get('failures') or {}).items():
        lines.append(f'  failed: {v} x {k}')
    band = summary.get('band_6_6')
    if band:
        lines.append(f'  band (6.6): measured half-width {band["measured_half_width_median_rad_s"]:.3f} rad/s '
                     f'(median of {band["columns"]} columns) vs b_p u_max / omega_p = {band["bound_rad_s"]:.3f}')
    for r in table or []:
        lines.append(f'  #{r["rank"]} {r["controller"]}: {100 * r["success_rate"]:.1f} %, median time to '
                     f'balance {r["median_time_to_balance"]:.2f} s')
    return '\n'.join(lines)
