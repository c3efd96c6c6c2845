"""``identify --check RIG.yaml``: does a rig still match its YAML?  Parameter by parameter (pure).

The short re-measurement (:func:`rwpend_ident.plan.plan` with ``check``) is fitted like a full
identification; each quantity then *matches* when the YAML's value lies within the measurement's
95 % confidence interval widened by a tolerance of what matters for control (a worn bearing moves
the friction by tens of percent, a loose wheel b_r and the lag), else it *differs*.
"""
from __future__ import annotations

#: relative tolerance per quantity (beside the confidence interval)
TOLERANCE = {'a': 0.005, 'b_p': 0.05, 'b_r': 0.02, 'omega_p': 0.003, 'friction_coulomb_pos': 0.05,
             'friction_viscous_pos': 0.05, 'friction_coulomb_neg': 0.05, 'friction_viscous_neg': 0.05,
             'friction_breakaway': 0.05, 'motor_time_constant': 0.2, 'pendulum_energy_time_constant': 0.25}


def compare(ident, rig) -> list[dict]:
    """One row per quantity of TOLERANCE: the YAML's value, the measured one with its CI, the
    deviation and the verdict ('matches' / 'DIFFERS')."""
    rows = []
    for name, tol in TOLERANCE.items():
        m, ci = ident.values[name]
        y = float(getattr(rig, name))
        dev = m - y
        ok = abs(dev) <= ci + tol * abs(y)
        rows.append({'name': name, 'yaml': y, 'measured': m, 'ci95': ci, 'deviation_pct': 100 * dev / y if y else None,
                     'tolerance_pct': 100 * tol, 'matches': bool(ok)})
    return rows


def format_rows(rows: list[dict]) -> str:
    lines = [f'{"quantity":30s} {"rig YAML":>11s} {"measured":>11s} {"+- (95 %)":>10s} {"dev %":>7s}  verdict']
    for r in rows:
        dev = f'{r["deviation_pct"]:+.1f}' if r['deviation_pct'] is not None else '-'
        verdict = 'matches' if r['matches'] else f'DIFFERS (tolerance {r["tolerance_pct"]:g} % + CI)'
        lines.append(f'{r["name"]:30s} {r["yaml"]:11.5g} {r["measured"]:11.5g} {r["ci95"]:10.2g} {dev:>7s}  {verdict}')
    return '\n'.join(lines)
