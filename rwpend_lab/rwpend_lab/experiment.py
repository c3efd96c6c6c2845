"""What an experiment of the lab is: its runs, its quantities (theory beside measurement), its figures.

Pure Python: no rclpy.  An :class:`Experiment` says *what* to run (a list of :class:`Run`, each
the settings of one run of the stack -- simulator set-up, estimator, controller, law -- and, for
the rig, what to ask of the student) and *how* to judge it (``analyze``: the recorded
:class:`rwpend_lab.data.RunData` of every run -> :class:`Analysis`).  The runner
(:mod:`rwpend_lab.runner`) does the running, :mod:`rwpend_lab.report` the writing.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Sequence

#: What an experiment may need (``lab list`` shows them).
NEEDS = {
    'sim': 'runs on the simulator',
    'rig': 'runs on the rig (--plant serial:PORT)',
    'bracket': 'wheel on the fixed bracket, pendulum locked (Fig. 3.1)',
    'torque-meter': 'a torque meter on the rotor axis',
    'release': 'a manual release of the pendulum',
    'raise': 'the pendulum raised upright by hand',
    'tap': 'a tap on the pendulum',
    'spin': 'the wheel spun by hand',
    'torque': 'a disturbance torque on the pendulum (rubber band)',
    'law': 'student code (--law FILE.py)',
}


class LabError(Exception):
    """A request the lab cannot carry out (unknown experiment, bad option): the reason."""


@dataclass(frozen=True)
class Prompt:
    """A manual step on the rig: the text for the student and how the lab detects it was done
    (``detect``: name of a detector of :mod:`rwpend_lab.manual`, with its arguments); shown
    ``wait_s`` s after the previous step; ``at``: when the simulator run does the same (s), which
    puts the rig run's time origin (:class:`rwpend_lab.manual.StepSequence`)."""

    text: str
    detect: str
    args: Mapping[str, float] = field(default_factory=dict)
    wait_s: float = 0.0
    at: float = 0.0


@dataclass(frozen=True)
class Run:
    """One run of the stack.  Parameter dicts are ROS parameters of the nodes (dotted names);
    ``sim`` is what the simulator does for the student (initial angle, taps, torques); on the rig
    the ``prompts`` ask for it instead."""

    name: str
    title: str
    duration: float
    mode: str = 'off'
    sim: Mapping[str, Any] = field(default_factory=dict)
    estimator: Mapping[str, Any] = field(default_factory=dict)
    controller: Mapping[str, Any] = field(default_factory=dict)
    law: str = ''                                   # law.file for mode 'law'
    law_params: Mapping[str, Any] = field(default_factory=dict)
    student: bool = False                           # --law FILE.py replaces ``law`` here
    prompts: Sequence[Prompt] = ()
    #: on the rig, the controller runs ``mode`` once this many prompts are done (``off`` before);
    #: 0: from the start, as on the simulator
    arm_after: int = 0

    def with_law(self, source: str) -> 'Run':
        from dataclasses import replace
        return replace(self, law=source, mode='law')


@dataclass
class Quantity:
    """One quantity the book derives: measured beside the model's theory (and the book's number)."""

    experiment: int
    name: str
    unit: str
    measured: float | None
    theory: float
    tolerance: float                  # absolute, in ``unit``
    book: float | str | None = None   # the book's printed value (None: the book prints none)
    ref: str = ''                     # equation / section / erratum
    note: str = ''
    run: str = ''

    @property
    def passed(self) -> bool:
        m = self.measured
        return m is not None and math.isfinite(m) and abs(m - self.theory) <= self.tolerance

    def as_dict(self) -> dict:
        return {'experiment': self.experiment, 'name': self.name, 'unit': self.unit,
                'measured': _num(self.measured), 'theory': _num(self.theory),
                'tolerance': _num(self.tolerance), 'pass': self.passed, 'book': _num(self.book),
                'ref': self.ref, 'note': self.note, 'run': self.run}


def _num(v):
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return float(v) if math.isfinite(v) else None
    return v


def within(experiment: int, name: str, unit: str, measured, theory: float, *, rel: float = 0.0,
           abs_tol: float = 0.0, **kw) -> Quantity:
    """A quantity whose tolerance is ``rel`` of |theory| plus ``abs_tol``."""
    m = None if measured is None else float(measured)
    return Quantity(experiment, name, unit, m, float(theory), rel * abs(float(theory)) + abs_tol, **kw)


@dataclass
class Figure:
    """A figure of the report: PNG bytes and a caption (the book's figure it corresponds to)."""

    name: str
    caption: str
    png: bytes


@dataclass
class Analysis:
    quantities: list[Quantity] = field(default_factory=list)
    figures: list[Figure] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Options:
    """What the student chose: the plant, a law file of their own, parameter overrides."""

    plant: str = 'sim'
    law: str = ''
    sets: Sequence[str] = ()

    @property
    def rig_plant(self) -> bool:
        return self.plant != 'sim'


@dataclass(frozen=True)
class Experiment:
    number: int
    title: str
    section: str
    figures: Sequence[str]
    needs: Sequence[str]
    runs: Callable[[Any, Options], list[Run]]
    analyze: Callable[[Any, Mapping[str, Any]], Analysis]
    questions: Sequence[str] = ()
    template: str = ''               # a template for --law (file in rwpend_lab/templates), '' = none
    summary: str = ''

    def plan(self, rig, options: Options) -> list[Run]:
        """The runs for these options (a student law put in, checked); LabError with the reason."""
        runs = self.runs(rig, options)
        if options.law:
            if not self.template:
                raise LabError(f'Experiment {self.number} asks for no law of your own (--law is for '
                               f'experiments {", ".join(str(n) for n in law_experiments())})')
            runs = [r.with_law(options.law) if r.student else r for r in runs]
        return runs


def law_experiments() -> list[int]:
    from .registry import EXPERIMENTS
    return [n for n, e in EXPERIMENTS.items() if e.template]
