"""What the console's page can ask and do, one method per request (the web server,
:mod:`rwpend_console.web`, only routes and checks access).

Every request names its rig (``DOMAIN:/NAMESPACE``). Bad input -- a malformed rig, an unknown
node, a value of the wrong type, a bag name that exists -- is a :class:`RequestError` with the
reason, and nothing is sent to the rig. What a node refuses comes back with the node's reason.
"""
from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

from rwpend_control.parameters import MODES

from . import bags, paramsvc
from .fmt import value_text
from .jobs import Analyses, Recording
from .labruns import LabRuns
from .modes import mode_buttons
from .panel import coerce_value, design_preview
from .rigs import node_name, parse_rig_id, rig_id
from .rosside import CallError, DomainWatcher

#: seconds the rig data of a controller is kept for design previews
RIG_CACHE_S = 30.0


class RequestError(Exception):
    def __init__(self, reason: str, status: int = 400) -> None:
        super().__init__(reason)
        self.reason = reason
        self.status = status


def _get(body: Any, key: str, kind, what: str):
    if not isinstance(body, dict) or key not in body:
        raise RequestError(f'missing {key!r} ({what})')
    v = body[key]
    if kind is float:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise RequestError(f'{key}: a finite number ({what}), got {v!r}')
        return float(v)
    if not isinstance(v, kind):
        raise RequestError(f'{key}: {what}, got {v!r}')
    return v


class ConsoleApp:
    def __init__(self, watchers: dict[int, DomainWatcher], bags_dir: Path, window_s: float,
                 lab: LabRuns | None = None) -> None:
        self.watchers = watchers
        self.lab = lab
        self.bags_dir = Path(bags_dir)
        self.window_s = window_s
        self.recordings: dict[str, Recording] = {}
        self.analyses = Analyses()
        self._rigs: dict[tuple[int, str], tuple[float, Any]] = {}

    # ------------------------------------------------------------ helpers
    def rig(self, text: Any) -> tuple[DomainWatcher, str, str]:
        """(watcher, namespace, rig id) of a request's ``rig``."""
        if not isinstance(text, str):
            raise RequestError(f'rig: DOMAIN:/NAMESPACE, got {text!r}')
        try:
            domain, ns = parse_rig_id(text, self.watchers)
        except ValueError as exc:
            raise RequestError(str(exc)) from None
        return self.watchers[domain], ns, rig_id(domain, ns)

    def _node(self, ns: str, node: Any) -> str:
        if not isinstance(node, str):
            raise RequestError(f'node: a node name, got {node!r}')
        try:
            return node_name(ns, node)
        except ValueError as exc:
            raise RequestError(str(exc)) from None

    @staticmethod
    def _call(fn, *args):
        try:
            return fn(*args)
        except CallError as exc:
            raise RequestError(str(exc), 503) from None

    # ------------------------------------------------------------ views
    def overview(self) -> dict:
        rows = []
        for domain, w in sorted(self.watchers.items()):
            for ns in w.rigs:
                rid = rig_id(domain, ns)
                rec = self.recordings.get(rid)
                rows.append({**w.summary(ns), 'id': rid, 'domain': domain,
                             'recording': rec.as_dict() if rec is not None and rec.running else None})
        return {'rigs': rows}

    def rig_info(self, rig: Any) -> dict:
        w, ns, rid = self.rig(rig)
        rec = self.recordings.get(rid)
        return {'id': rid, 'domain': w.domain, 'ns': ns, 'nodes': w.node_names(ns), 'lights': w.lights(ns),
                'summary': w.summary(ns), 'estop': w.estop_state(ns),
                'recording': rec.as_dict() if rec is not None else None,
                'analyses': self.analyses.state()}

    def modes(self, rig: Any) -> dict:
        """The mode buttons of the rig's controller: mode ``law`` is usable only with a
        ``law.file`` (read from the controller; when it cannot be read the controller decides)."""
        w, ns, _ = self.rig(rig)
        fqn = self._node(ns, 'controller')
        try:
            got = paramsvc.get_typed(w.call, fqn, ['law.file'])
            law_file, why = (str(got['law.file'][1]) if 'law.file' in got else ''), ''
        except CallError as exc:
            law_file, why = None, str(exc)
        return {'node': fqn, 'law_file': law_file, 'modes': mode_buttons(MODES, law_file, why)}

    def params(self, rig: Any, node: Any) -> dict:
        w, ns, _ = self.rig(rig)
        fqn = self._node(ns, node)
        fields = self._call(paramsvc.read_fields, w.call, fqn)
        return {'node': fqn, 'fields': [f.as_dict() for f in fields]}

    def design(self, body: Any) -> dict:
        """The gains a design would give (nothing is set)."""
        w, ns, _ = self.rig(_get(body, 'rig', str, 'the rig'))
        group = _get(body, 'group', str, 'a design group: balance, patch, ...')
        changes = _get(body, 'changes', dict, 'the design parameters typed, {name: value}')
        fqn = self._node(ns, body.get('node', 'controller'))
        names = [n for n in self._call(paramsvc.list_names, w.call, fqn) if n.startswith(f'{group}.design.')]
        fields = {f.name: f for f in self._call(paramsvc.read_fields, w.call, fqn, names)} if names else {}
        typed = {}
        for name, raw in changes.items():
            if name not in fields:
                return {'ok': False, 'gains': {}, 'stable': None,
                        'reason': f'{fqn} has no design parameter {name!r} of {group}'}
            try:
                typed[name] = coerce_value(fields[name], raw)
            except ValueError as exc:
                return {'ok': False, 'gains': {}, 'stable': None, 'reason': str(exc)}
        designs = {n: f.value for n, f in fields.items()}
        return design_preview(self._rig_model(w, fqn), group, designs, typed).as_dict()

    def _rig_model(self, w: DomainWatcher, fqn: str):
        from rwpend_model.rig import Rig
        key = (w.domain, fqn)
        t, rig = self._rigs.get(key, (0.0, None))
        if rig is None or time.monotonic() - t > RIG_CACHE_S:
            names = [n for n in self._call(paramsvc.list_names, w.call, fqn) if n.startswith('rig.')]
            values = {n: v for n, (_, v) in self._call(paramsvc.get_typed, w.call, fqn, names).items()}
            try:
                rig = Rig.from_params(values)
            except ValueError as exc:
                raise RequestError(f'{fqn}: its rig parameters do not make a rig: {exc}', 503) from None
            self._rigs[key] = (time.monotonic(), rig)
        return rig

    def bag_list(self) -> dict:
        return {'folder': str(self.bags_dir), 'bags': bags.list_bags(self.bags_dir),
                'analyses': self.analyses.state()}

    def plot(self, name: Any) -> Path:
        try:
            return bags.plot_file(self.bags_dir, name)
        except ValueError as exc:
            raise RequestError(str(exc), 404) from None

    def _lab(self) -> LabRuns:
        if self.lab is None:
            raise RequestError('this console runs no lab experiments', 404)
        return self.lab

    def lab_state(self) -> dict:
        lab = self._lab()
        try:
            exps = lab.experiments()
        except ValueError as exc:
            raise RequestError(str(exc), 503) from None
        return {'experiments': exps or [], 'loading': exps is None, **lab.state()}

    def lab_report(self, name: Any) -> Path:
        try:
            return self._lab().report(name)
        except ValueError as exc:
            raise RequestError(str(exc), 404) from None

    def lab_run(self, body: Any) -> dict:
        number = _get(body, 'experiment', int, 'the number of an experiment')
        if isinstance(number, bool):
            raise RequestError(f'experiment: the number of an experiment, got {number!r}')
        try:
            return self._lab().start(number)
        except ValueError as exc:
            raise RequestError(str(exc), 409 if 'is running' in str(exc) else 400) from None

    def lab_stop(self, body: Any) -> dict:
        try:
            return self._lab().stop(_get(body, 'run', str, 'the name of a lab run'))
        except ValueError as exc:
            raise RequestError(str(exc)) from None

    # ------------------------------------------------------------ actions
    def set_param(self, body: Any) -> dict:
        w, ns, _ = self.rig(_get(body, 'rig', str, 'the rig'))
        fqn = self._node(ns, _get(body, 'node', str, 'a node of the rig'))
        name = _get(body, 'name', str, 'a parameter name')
        if 'value' not in body:
            raise RequestError("missing 'value'")
        fields = self._call(paramsvc.read_fields, w.call, fqn, [name])
        if not fields:
            raise RequestError(f'{fqn} has no parameter {name!r}', 404)
        try:
            value = coerce_value(fields[0], body['value'])
        except ValueError as exc:
            return {'ok': False, 'reason': str(exc), 'value': fields[0].value,
                    'value_text': value_text(fields[0].type, fields[0].value)}
        (_, ok, reason), = self._call(paramsvc.set_values, w.call, fqn, {name: value})
        type_name, now = self._call(paramsvc.get_typed, w.call, fqn, [name]).get(name, (fields[0].type, None))
        return {'ok': ok, 'reason': reason if not ok else '', 'value': now, 'value_text': value_text(type_name, now)}

    def mode(self, body: Any) -> dict:
        from rwpend_msgs.srv import SetMode
        w, ns, _ = self.rig(_get(body, 'rig', str, 'the rig'))
        mode = _get(body, 'mode', str, 'a mode')
        if mode not in MODES:
            raise RequestError(f'mode: one of {", ".join(MODES)}, got {mode!r}')
        r = self._call(w.call, SetMode, f'{ns.rstrip("/")}/controller/set_mode', SetMode.Request(mode=mode))
        return {'ok': bool(r.success), 'message': r.message}

    def tap(self, body: Any) -> dict:
        from rwpend_msgs.srv import Disturb
        w, ns, _ = self.rig(_get(body, 'rig', str, 'the rig'))
        dv = _get(body, 'dv', float, 'the jump of theta_dot, rad/s')
        r = self._call(w.call, Disturb, f'{ns.rstrip("/")}/sim/disturb',
                       Disturb.Request(kind=Disturb.Request.TAP, magnitude=dv, duration=0.0))
        return {'ok': bool(r.success), 'message': r.message}

    def estop(self, body: Any, on: bool = True) -> dict:
        """The e-stop: the rig's latched topic at once, then each plant's ``estop`` service for
        its answer. ``clicked_ms`` (the page's clock at the click) stamps the console's record.
        ``estop``: the rig's e-stop as its plant reported it after the answers."""
        from std_srvs.srv import SetBool
        w, ns, _ = self.rig(_get(body, 'rig', str, 'the rig'))
        clicked = body.get('clicked_ms')
        clicked_ns = int(clicked * 1e6) if isinstance(clicked, (int, float)) and not isinstance(clicked, bool) \
            and math.isfinite(clicked) else None
        w.publish_estop(ns, on, clicked_ns)
        answers = []
        for name in w.service_names(ns, '/estop', 'std_srvs/srv/SetBool'):
            try:
                r = w.call(SetBool, name, SetBool.Request(data=on), timeout=2.0)
                answers.append({'service': name, 'ok': bool(r.success), 'message': r.message})
            except CallError as exc:
                answers.append({'service': name, 'ok': False, 'message': str(exc)})
        return {'ok': True, 'on': on, 'topic': f'{ns.rstrip("/")}/estop', 'answers': answers,
                'estop': w.estop_state(ns)}

    def record(self, body: Any) -> dict:
        w, ns, rid = self.rig(_get(body, 'rig', str, 'the rig'))
        action = _get(body, 'action', str, 'start or stop')
        rec = self.recordings.get(rid)
        if action == 'stop':
            if rec is None or not rec.running:
                raise RequestError(f'{rid} is not being recorded by this console')
            code = rec.stop()
            return {'ok': code == 0, 'bag': rec.path.name, 'exit': code}
        if action != 'start':
            raise RequestError(f'action: start or stop, got {action!r}')
        if rec is not None and rec.running:
            raise RequestError(f'{rid} is already being recorded to {rec.path.name}')
        try:
            path = bags.bag_dir(self.bags_dir, _get(body, 'name', str, "the new bag's name"))
        except ValueError as exc:
            raise RequestError(str(exc)) from None
        if path.exists():
            raise RequestError(f'a bag {path.name} exists already in {self.bags_dir} (choose another name)')
        topics = w.rig_topics(ns)
        if not any(t.startswith(ns.rstrip('/') + '/') for t in topics):
            raise RequestError(f'no topics of {rid} to record (is the rig running?)', 503)
        self.bags_dir.mkdir(parents=True, exist_ok=True)
        self.recordings[rid] = Recording(path, topics, w.domain)
        return {'ok': True, 'bag': path.name, 'topics': topics}

    def analyze(self, body: Any) -> dict:
        try:
            path = bags.bag_dir(self.bags_dir, _get(body, 'bag', str, 'a bag of the folder'))
        except ValueError as exc:
            raise RequestError(str(exc)) from None
        if bags.describe_bag(path) is None:
            raise RequestError(f'no bag {path.name} in {self.bags_dir}', 404)
        if any(r.running and r.path == path for r in self.recordings.values()):
            raise RequestError(f'{path.name} is still being recorded')
        started = self.analyses.start(path)
        return {'ok': True, 'bag': path.name, 'started': started}

    def close(self) -> None:
        for rec in self.recordings.values():
            rec.stop()
        if self.lab is not None:
            self.lab.close()
