"""``rwpend gains DESIGN``: print the book's gain designs and their closed-loop poles.

    rwpend gains pdd --w0 1.5wp --zeta 0.707 --alpha 0.2 --book-g
    rwpend gains pdpd --w0 wp --zeta 1 --w2 0.5wp --zeta2 0.707
    rwpend gains patch --w0 1.5wp --json

DESIGN: pd (4.3), pi (3.15-3.16), wheel_pd (3.18), pdd (4.11), pdpd (4.15), patch (6.3).
``--book-g`` uses the book's g = 9.91 (reproduces its printed numbers, ERRATA E01); otherwise
the shipped rig YAML, or ``--rig FILE`` (a complete rig file, e.g. an identified ``DIR/rig.yaml``:
every key, named in the error when one is missing).  The gains printed without options are the
controller's default gain sets for that rig (``ControllerConfig.designed``).  The printed parameter names are those of the ``controller``
node; ``--apply`` sets them on the running controller (all in one atomic request, validated
by the node: refused as a whole, with the reason, if invalid).  Exit status 2 on bad arguments,
1 when the controller refuses or cannot be reached.
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from rwpend_model.rig import book_rig, load_rig, load_rig_file

from . import design

#: design -> (default w0, default zeta, node parameter names)
DEFAULTS = {
    'pd': ('wp', 1.0),
    'pi': ('20', 1.0),
    'wheel_pd': ('10', 0.707),
    'pdd': ('1.5wp', 0.707),
    'pdpd': ('wp', 0.707),
    'patch': ('1.5wp', 0.707),
}


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # exit status 2 with a clear message (argparse's default too)
        self.print_usage(sys.stderr)
        print(f'rwpend gains: error: {message}', file=sys.stderr)
        raise SystemExit(2)


def _parser() -> argparse.ArgumentParser:
    p = _Parser(prog='rwpend gains', description='Gain designs of the book and their closed-loop poles.')
    p.add_argument('design', choices=design.DESIGNS, help='which design')
    p.add_argument('--w0', help='omega0 (rad/s) or a multiple of omega_p like 1.5wp (omega1 for pdpd)')
    p.add_argument('--zeta', type=float, help='damping (zeta1 for pdpd)')
    p.add_argument('--alpha', type=float, default=0.2, help='pdd: real pole -alpha*omega0 (default 0.2)')
    p.add_argument('--w2', default=None, help='pdpd: omega2 (default: = w0)')
    p.add_argument('--zeta2', type=float, default=1.0, help='pdpd: zeta2 (default 1)')
    p.add_argument('--down', action='store_true', help='pd: also print the up-down transformed gains (E21)')
    p.add_argument('--book-g', action='store_true', help="use the book's g = 9.91 (E01)")
    p.add_argument('--rig', help='a complete rig YAML, e.g. an identified DIR/rig.yaml (default: the shipped rig.yaml)')
    p.add_argument('--json', action='store_true', help='print JSON')
    p.add_argument('--apply', action='store_true',
                   help='set the gains on the running controller (validated there; refused as a whole)')
    p.add_argument('--ns', default='/rwpend', help='namespace of the running rig (with --apply)')
    return p


def _poles_list(poles) -> list:
    return [[float(p.real), float(p.imag)] for p in poles]


def compute(args: argparse.Namespace) -> dict:
    """The design result as a dict (raises ValueError for bad values)."""
    if args.book_g and args.rig:
        raise ValueError("--book-g is the book's rig: it excludes --rig")
    try:
        rig = book_rig() if args.book_g else load_rig_file(args.rig) if args.rig else load_rig()
    except OSError as exc:
        raise ValueError(f'--rig: {exc}') from None
    w0_text, zeta_default = DEFAULTS[args.design]
    w0_text = args.w0 if args.w0 is not None else w0_text
    zeta = args.zeta if args.zeta is not None else zeta_default
    w0 = design.parse_omega(w0_text, rig)
    out: dict = {'design': args.design, 'g': rig.g, 'a': rig.a, 'b_p': rig.b_p, 'b_r': rig.b_r,
                 'omega_p': rig.omega_p, 'omega0': w0, 'zeta': zeta}
    d = args.design
    if d in ('pi', 'wheel_pd'):
        wg = design.pi_control(rig, w0, zeta) if d == 'pi' else design.wheel_pd(rig, w0, zeta)
        if d == 'pi':
            params = {'wheel.kp': wg.kdr, 'wheel.ki': wg.ki}
            poly = [1.0, rig.b_r * wg.kdr, rig.b_r * wg.ki / rig.sample_period]
        else:
            params = {'wheel_angle.kpr': wg.kpr, 'wheel_angle.kdr': wg.kdr}
            poly = [1.0, rig.b_r * wg.kdr, rig.b_r * wg.kpr]
        out.update(gains=wg.as_dict(), params=params, poles=_poles_list(np.roots(poly)),
                   stable=True, reason='wheel loop (3.12) without friction and lags')
        return out
    if d == 'pd':
        g = design.pd_control(rig, w0, zeta)
    elif d == 'pdd':
        out['alpha'] = args.alpha
        g = design.pddcontrol(rig, w0, zeta, args.alpha)
    elif d == 'pdpd':
        w2 = design.parse_omega(args.w2, rig) if args.w2 is not None else w0
        out.update(omega2=w2, zeta2=args.zeta2)
        g = design.pdpdcontrol(rig, w0, zeta, w2, args.zeta2)
    else:
        g = design.pddcontrolwpatch(rig, w0, zeta)
    group = 'patch' if d == 'patch' else 'balance'
    params = {f'{group}.{k}': v for k, v in g.as_dict().items() if not (group == 'patch' and k == 'kpr')}
    ok, reason = design.check_stable(rig, g, allow_wheel_drift=(d == 'pd'))
    out.update(gains=g.as_dict(), params=params, poles=_poles_list(design.closed_loop_poles(rig, g)),
               stable=ok, reason=reason)
    if d == 'pd' and args.down:
        out['down'] = design.up_down(rig, g).as_dict()
    return out


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        out = compute(args)
    except ValueError as exc:
        print(f'rwpend gains: error: {exc}', file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(out, indent=2))
        return 0
    extra = ''
    if 'alpha' in out:
        extra = f', alpha = {out["alpha"]:g}'
    if 'omega2' in out:
        extra = f', omega2 = {out["omega2"]:.4g} rad/s, zeta2 = {out["zeta2"]:g}'
    print(f'{out["design"]}: omega0 = {out["omega0"]:.4g} rad/s ({out["omega0"] / out["omega_p"]:.3g} omega_p), '
          f'zeta = {out["zeta"]:g}{extra}')
    print(f'rig: g = {out["g"]:g}, a = {out["a"]:.4f}, b_p = {out["b_p"]:.4f}, b_r = {out["b_r"]:.2f}, '
          f'omega_p = {out["omega_p"]:.4f}')
    for name, v in out['params'].items():
        print(f'  {name} = {v:.6g}')
    if 'down' in out:
        print(f'  hanging-down test (up-down transformation): kpp = {out["down"]["kpp"]:.6g}, '
              f'kdp = {out["down"]["kdp"]:.6g}')
    poles = ', '.join(f'{re:.4g}{im:+.4g}j' if abs(im) > 1e-5 * max(1.0, abs(re)) else f'{re:.4g}'
                      for re, im in out['poles'])
    print(f'closed-loop poles: {poles}')
    print(out['reason'] if out['stable'] else f'NOT STABLE: {out["reason"]}')
    if out['design'] == 'pd':
        print('  (the controller accepts it as balance gains only with allow_wheel_drift:=true)')
    if args.apply:
        return apply(out['params'], args.ns)
    return 0


def apply(params: dict, namespace: str) -> int:
    """Set ``params`` on the running controller atomically (SetParametersAtomically)."""
    from rwpend_ros.tools import RosTool, ToolError, to_parameter_value
    try:
        with RosTool(namespace) as t:
            ok, reason = t.set_params_atomically('controller', {n: to_parameter_value(float(v))
                                                                for n, v in params.items()})
    except ToolError as exc:
        print(f'rwpend gains: error: {exc}', file=sys.stderr)
        return 1
    if not ok:
        print(f'rwpend gains: the controller refused the gains: {reason}', file=sys.stderr)
        return 1
    print(f'applied to {namespace.rstrip("/")}/controller')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
