"""The rig's e-stop as the console shows it (pure: reports and requests in, a state out; no rclpy).

The e-stop is latched in the plant -- the simulator (``sim``) or the driver -- and only the plant
knows whether it holds the motor at zero: anyone may raise or clear it (this console, another
one, ``./rwpend estop [--clear]``, a call of the plant's ``~/estop`` service, the ``estop``
topic). The plant says its state in every report on ``/diagnostics`` (value ``estop``: True /
False; about once a second, and at once when it changes). So the console's e-stop shows what
the plant last said, never what the console itself last asked for.

:class:`EstopTracker` (one per rig) takes each plant report (:meth:`EstopTracker.report`) and
each request this console sends (:meth:`EstopTracker.requested`), with the console's clock at
each; :meth:`EstopTracker.state` decides:

* ``raised`` / ``clear``: what the fresh reports say (a report is fresh for
  :data:`STALE_AFTER_S`); raised when any plant of the rig says raised;
* ``unknown``: no plant reports (yet), the last report is older than that (the console lost
  the rig), or the reports carry no e-stop value;
* who changed it last, as far as the console can tell (``by``): ``console`` when the change
  came after this console asked for it, ``elsewhere`` when it came otherwise, '' when the
  console has not seen it change;
* ``pending``: this console asked for the other state less than :data:`CONFIRM_S` ago and the
  plant has not reported the change yet; past that, the text says the plant did not take it.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

#: seconds without a plant report before its e-stop state is unknown (plants report every second)
STALE_AFTER_S = 3.0
#: seconds a request of this console waits for the plant's report of the change (the plant
#: reports it at once; a report already on its way when the request went out may come first)
CONFIRM_S = 2.0
#: the values of the ``estop`` key in a plant's report
VALUES = {'True': True, 'False': False}
ELSEWHERE = '(./rwpend estop, the plant\'s ~/estop service or estop topic, another console)'


@dataclass(frozen=True)
class PlantReport:
    """The newest e-stop report of one plant."""

    received: float              # the console's clock (s) when it came
    raised: bool | None          # None: the report had no readable estop value
    value: str                   # the value as sent
    changed: float | None        # when the reported state last changed (None: not seen to change)


@dataclass(frozen=True)
class Request:
    """This console's newest e-stop request to the rig."""

    on: bool
    at: float                    # the console's clock (s) when it was sent


@dataclass(frozen=True)
class EstopState:
    state: str                   # 'raised', 'clear' or 'unknown'
    text: str                    # what the page shows beside the button
    by: str = ''                 # 'console', 'elsewhere' or '' (not known)
    pending: str = ''            # 'raise' or 'clear': asked by this console, not reported yet
    unconfirmed: bool = False    # this console's request was not taken within CONFIRM_S
    plants: tuple[str, ...] = ()  # the plants whose reports decide
    age_s: float | None = None   # age of the newest report that decides

    def as_dict(self) -> dict:
        d = asdict(self)
        d['plants'] = list(self.plants)
        return d


def _names(names) -> str:
    return ', '.join(sorted(names))


class EstopTracker:
    """The e-stop reports of one rig's plants and this console's requests (module docstring)."""

    def __init__(self) -> None:
        self.plants: dict[str, PlantReport] = {}
        self.request: Request | None = None

    def report(self, plant: str, value: str | None, now: float) -> None:
        """A report of ``plant`` ('sim', 'driver') with its ``estop`` value (None: it had none),
        taken at ``now`` (s)."""
        if not isinstance(plant, str) or not plant:
            raise ValueError(f'plant: a node name, got {plant!r}')
        text = '' if value is None else str(value)
        raised = VALUES.get(text)
        prev = self.plants.get(plant)
        if prev is None:
            changed = None
        elif prev.raised == raised:
            changed = prev.changed
        else:
            changed = now
        self.plants[plant] = PlantReport(now, raised, text, changed)

    def requested(self, on: bool, now: float) -> None:
        """This console sends a raise (``on``) or a clear at ``now`` (s)."""
        if not isinstance(on, bool):
            raise ValueError(f'on: True (raise) or False (clear), got {on!r}')
        self.request = Request(on, now)

    def state(self, now: float, stale_after: float = STALE_AFTER_S, confirm_s: float = CONFIRM_S) -> EstopState:
        """What the console shows at ``now`` (module docstring)."""
        if not self.plants:
            return EstopState('unknown', 'e-stop state unknown: no plant (simulator or driver) reports '
                                         'yet -- is the rig running?')
        fresh = {n: p for n, p in self.plants.items() if now - p.received <= stale_after}
        if not fresh:
            name, last = max(self.plants.items(), key=lambda kv: kv[1].received)
            said = {True: 'raised', False: 'clear', None: 'no e-stop value'}[last.raised]
            return EstopState('unknown', f'e-stop state unknown: the console lost the rig -- no report '
                                         f'from {name} for {now - last.received:.0f} s (it said {said})',
                              plants=(name,), age_s=now - last.received)
        known = {n: p for n, p in fresh.items() if p.raised is not None}
        if not known:
            bad = ', '.join(f'{n}: {p.value!r}' for n, p in sorted(fresh.items()))
            return EstopState('unknown', f'e-stop state unknown: the plant reports no e-stop value ({bad})',
                              plants=tuple(sorted(fresh)))
        raised = any(p.raised for p in known.values())
        deciding = {n: p for n, p in known.items() if p.raised == raised}
        names = _names(deciding)
        changes = [p.changed for p in deciding.values() if p.changed is not None]
        changed = max(changes) if changes else None
        age = now - max(p.received for p in deciding.values())
        req = self.request
        by = ''
        if changed is not None:
            by = 'console' if req is not None and req.on == raised and changed >= req.at else 'elsewhere'
        pending, unconfirmed = '', False
        if req is not None and req.on != raised and (changed is None or changed < req.at):
            if now - req.at < confirm_s:
                pending = 'raise' if req.on else 'clear'
            else:
                unconfirmed = True
        state = 'raised' if raised else 'clear'
        if raised:
            who = {'console': ' from this console', 'elsewhere': f' elsewhere {ELSEWHERE}'}.get(by, '')
            text = f'E-STOP raised{who}: the motor is held at zero ({names} reports)'
        else:
            who = {'console': ': cleared from this console', 'elsewhere': f': cleared elsewhere {ELSEWHERE}'}.get(by, '')
            text = f'e-stop clear ({names} reports){who}'
        if pending == 'raise':
            text = f'E-STOP sent: waiting for {names} to report it -- until then the motor may be driven'
        elif pending == 'clear':
            text = f'clear sent: waiting for {names} to report it -- the e-stop still holds the motor at zero'
        elif unconfirmed and req.on:
            text = (f'E-STOP NOT CONFIRMED: this console raised it {now - req.at:.0f} s ago and {names} '
                    f'still reports it clear -- stop the rig by hand')
        elif unconfirmed:
            text = (f'clear not taken: this console cleared it {now - req.at:.0f} s ago and {names} '
                    f'still reports the e-stop raised')
        return EstopState(state, text, by, pending, unconfirmed, tuple(sorted(deciding)), age)
