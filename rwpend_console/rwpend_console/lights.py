"""The diagnostics as status lights (pure: statuses in, lights out; no rclpy).

Every node of a rig publishes one DiagnosticStatus on ``/diagnostics`` about once a second,
named ``<namespace>/<node>`` (``/rwpend/controller``) or ``<namespace>/<node>: <what>``
(``/rwpend/sim: plant``). :class:`StatusBoard` keeps the newest status of each name with the
time it came, and gives per rig:

* a light per node (its level and message; ``stale`` when nothing came for
  :data:`STALE_AFTER_S`);
* four lights the lab asks about first: late samples (the plant's share of late commands),
  timeouts (the command timeout: the motor held at zero), faults (the controller's), e-stop
  (the plant's state, :mod:`rwpend_console.estop`: also :meth:`StatusBoard.estop`);
* a summary row for the lab's overview (mode, law, worst level, e-stop).

Every light has its reason in ``message`` (the page shows it beside the light) and the facts
behind it in ``facts``.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Mapping

from .estop import EstopState, EstopTracker

#: seconds without a status before a node's light goes stale (nodes report every second)
STALE_AFTER_S = 3.0
LEVELS = ('ok', 'warn', 'error', 'stale')        # DiagnosticStatus OK, WARN, ERROR, STALE
#: late commands (percent of the samples) above which the late light is yellow / red (1 %:
#: the plant's own 'slow' verdict, rwpend_ros.health)
LATE_WARN_PERCENT, LATE_ERROR_PERCENT = 0.1, 1.0
PLANT_NODES = ('sim', 'driver')
#: statuses not about a node of the rig (the console's own record of an e-stop from its page)
IGNORED_NODES = ('console',)
#: key-values worth showing beside a node's light, when it has them
FACTS = ('mode', 'law', 'estimator', 'loop_late_percent', 'loop_late_commands', 'timeouts',
         'timeout_samples', 'rejected_commands', 'refused_samples', 'stale_episodes', 'estop',
         'loop_dead', 'sim_time', 'lifecycle', 'connected')


def split_status_name(name: str) -> tuple[str, str]:
    """'/rwpend/sim: plant' -> ('/rwpend', 'sim'); '/rig2/controller' -> ('/rig2', 'controller');
    'controller' -> ('/', 'controller')."""
    path = name.split(':', 1)[0].strip()
    ns, _, node = path.rpartition('/')
    return (ns if ns.startswith('/') else '/' + ns if ns else '/'), node


@dataclass
class Light:
    key: str
    label: str
    level: str                # one of LEVELS
    message: str = ''
    facts: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return asdict(self)


def _level(n: int) -> str:
    return LEVELS[n] if isinstance(n, int) and 0 <= n < len(LEVELS) else 'error'


def _worst(levels) -> str:
    rank = {'ok': 0, 'stale': 1, 'warn': 2, 'error': 3}
    return max(levels, key=rank.__getitem__, default='stale')


def _float(v: Any) -> float | None:
    try:
        return float(v)
    except (TypeError, ValueError):
        return None


class StatusBoard:
    """The newest status of every diagnostic name, and what it says per rig."""

    def __init__(self) -> None:
        #: name -> (receive time s, level number, message, values)
        self.statuses: dict[str, tuple[float, int, str, dict]] = {}
        #: rig -> its plants' e-stop reports and this console's requests
        self.estops: dict[str, EstopTracker] = {}

    def update(self, name: str, level: int, message: str, values: Mapping[str, str], now: float) -> None:
        self.statuses[name] = (now, level, message, dict(values))
        ns, node = split_status_name(name)
        if node in PLANT_NODES:
            self.estops.setdefault(ns, EstopTracker()).report(node, values.get('estop'), now)

    def estop_requested(self, rig: str, on: bool, now: float) -> None:
        """This console sends a raise (``on``) or a clear of the e-stop of ``rig``."""
        self.estops.setdefault(rig, EstopTracker()).requested(on, now)

    def estop(self, rig: str, now: float) -> EstopState:
        """The e-stop of ``rig`` as its plant last reported it (:mod:`rwpend_console.estop`)."""
        return self.estops.get(rig, EstopTracker()).state(now, STALE_AFTER_S)

    def rigs(self) -> list[str]:
        return sorted({split_status_name(n)[0] for n in self.statuses})

    def nodes(self, rig: str, now: float) -> dict[str, tuple[str, str, dict]]:
        """{node: (level name, message, values)} of a rig (stale ones marked)."""
        out = {}
        for name, (t, level, msg, values) in sorted(self.statuses.items()):
            ns, node = split_status_name(name)
            if ns != rig or node in IGNORED_NODES:
                continue
            if now - t > STALE_AFTER_S:
                out[node] = ('stale', f'no diagnostics for {now - t:.0f} s (last: {msg})', values)
            else:
                out[node] = (_level(level), msg, values)
        return out

    def lights(self, rig: str, now: float) -> list[Light]:
        """The four lab lights first, then one per node."""
        nodes = self.nodes(rig, now)
        plant = next((nodes[n] for n in PLANT_NODES if n in nodes), None)
        out = [_late_light(plant), _timeout_light(plant), _fault_light(nodes.get('controller')),
               _estop_light(self.estop(rig, now))]
        for node, (level, msg, values) in nodes.items():
            out.append(Light(f'node:{node}', node, level, msg,
                             {k: values[k] for k in FACTS if k in values}))
        return out

    def summary(self, rig: str, now: float) -> dict:
        """One row of the lab overview."""
        nodes = self.nodes(rig, now)
        ctrl = nodes.get('controller', ('stale', '', {}))[2]
        plant = next((nodes[n] for n in PLANT_NODES if n in nodes), None)
        return {'ns': rig, 'mode': ctrl.get('mode', ''), 'law': ctrl.get('law', ''),
                'level': _worst(x.level for x in self.lights(rig, now)) if nodes else 'stale',
                'estop': self.estop(rig, now).state == 'raised',
                'plant': next((n for n in PLANT_NODES if n in nodes), ''),
                'nodes': sorted(nodes)}


def _late_light(plant) -> Light:
    if plant is None:
        return Light('late', 'late samples', 'stale', 'no plant (simulator or driver) reports')
    level, _, values = plant
    pct = _float(values.get('loop_late_percent'))
    if level == 'stale' or pct is None:
        return Light('late', 'late samples', 'stale', 'not reported')
    lvl = 'error' if pct >= LATE_ERROR_PERCENT else 'warn' if pct >= LATE_WARN_PERCENT else 'ok'
    return Light('late', 'late samples', lvl,
                 f'{pct:.3f} % of the commands late ({values.get("loop_late_commands", "?")})')


def _timeout_light(plant) -> Light:
    if plant is None or plant[0] == 'stale':
        return Light('timeouts', 'timeouts', 'stale', 'no plant reports')
    level, msg, values = plant
    dead = values.get('loop_dead') == 'True'
    now_out = 'timeout' in msg
    count = values.get('timeouts', '0')
    lvl = 'error' if dead else 'warn' if now_out or count not in ('0', '') else 'ok'
    text = msg if dead or now_out else f'{count} command timeouts'
    return Light('timeouts', 'timeouts', lvl, text)


def _fault_light(ctrl) -> Light:
    if ctrl is None:
        return Light('faults', 'faults', 'stale', 'no controller reports')
    level, msg, _ = ctrl
    return Light('faults', 'faults', level, msg if level != 'ok' else 'no fault')


def _estop_light(st: EstopState) -> Light:
    level = {'raised': 'error', 'clear': 'ok'}.get(st.state, 'stale')
    if st.unconfirmed:
        level = 'error'
    elif st.pending:
        level = 'warn'
    return Light('estop', 'e-stop', level, st.text)
