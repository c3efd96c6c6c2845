"""Writing a rig YAML: the format of rwpend_model/config/rig.yaml, every key, read back before use.

Pure Python (no rclpy).  The file is a ROS 2 parameters file whose ``/**`` section holds every
field of :class:`rwpend_model.rig.Rig` under ``rig:``, in the order of the shipped file, so any
node loads it with ``--rig FILE`` (or ``--params-file FILE`` on a full ROS install).  The model
parameters a, b_p, b_r, omega_p are not in it: rwpend_model.rig computes them from the data.
"""
from __future__ import annotations

import dataclasses
import math
import os
import tempfile
from pathlib import Path
from typing import Mapping, Sequence

import yaml

from rwpend_model.rig import Rig, load_rig_file

#: Unit and meaning of every field (the comments of the written file).
DESCRIPTION = {
    'g': 'm/s^2, gravity (ERRATA E01: 9.81, the book printed its numbers with 9.91)',
    'm_p': 'kg, pendulum mass', 'm_r': 'kg, rotor (wheel + motor rotor) mass',
    'l_p': "m, pivot to the pendulum's centre of mass", 'l_r': "m, pivot to the rotor's centre of mass",
    'j_p': 'kg m^2, pendulum inertia about its centre of mass', 'j_r': 'kg m^2, rotor inertia about its axis',
    'k_m': 'Nm/A, motor torque constant', 'r_a': 'ohm, armature resistance', 'l_a': 'H, armature inductance',
    'i_max': 'A, amplifier current limit (u = u_max)', 'v_max': 'V, amplifier voltage (back-EMF cut-off, 2.13)',
    'k_u': 'Nm per control unit (2.14)', 'u_max': 'control units, |u| <= u_max',
    'motor_time_constant': 's, current loop lag T_e (first order)',
    'pwm_steps': 'PWM duty resolution per polarity (Section 2.5); 0 = none',
    'counts_per_rev': 'both encoders, counts per revolution', 'sample_period': 's, h',
    'friction_coulomb_pos': 'units, F = c+ + v+ w for w > 0 (3.17), w = theta_r\' - theta\'',
    'friction_viscous_pos': 'units per rad/s', 'friction_coulomb_neg': 'units, F = -c- + v- w for w < 0 (3.17)',
    'friction_viscous_neg': 'units per rad/s',
    'friction_breakaway': 'units: the rotor sticks while the torque across its bearing stays below this',
    'pendulum_energy_time_constant': 's, pendulum-axis friction (energy decay, Fig. 2.3); 0 = none',
}


def example_rig_file() -> Path:
    """A rig that is not the book's (heavier pendulum and rotor, more friction and stiction, a
    slower current loop), shipped as the simulated truth of the examples and tests."""
    return Path(__file__).resolve().parent / 'config' / 'heavy_rig.yaml'


def format_value(v) -> str:
    """A number as YAML that every YAML reader takes for that number (a float always has a '.':
    PyYAML reads ``1e-05`` as a string)."""
    if isinstance(v, int) and not isinstance(v, bool):
        return str(v)
    s = f'{float(v):.9g}'
    mant, e, exp = s.partition('e')
    if '.' not in mant:
        mant += '.0'
    return mant + (e + exp if e else '')


def rig_yaml(rig: Rig, header: Sequence[str] = (), notes: Mapping[str, str] | None = None) -> str:
    """The text of a rig YAML for ``rig``: ``header`` lines as comments on top, ``notes[field]``
    appended to that field's comment (e.g. 'identified: 0.2489 +- 0.0011 (95 %)')."""
    notes = notes or {}
    lines = [f'# {h}'.rstrip() for h in header]
    lines += ['/**:', '  ros__parameters:', '    rig:']
    for f in dataclasses.fields(Rig):
        text = f'      {f.name}: {format_value(getattr(rig, f.name))}'
        comment = DESCRIPTION.get(f.name, '')
        if f.name in notes:
            comment = f'{comment} -- {notes[f.name]}' if comment else notes[f.name]
        lines.append(f'{text:<43} # {comment}' if comment else text)
    return '\n'.join(lines) + '\n'


def write_rig(path: str | Path, rig: Rig, header: Sequence[str] = (), notes: Mapping[str, str] | None = None) -> Path:
    """Write the rig YAML and read it back (:func:`rwpend_model.rig.load_rig_file`): the file on disk
    gives exactly ``rig`` (else ValueError, and nothing is left at ``path``).  Written to a temporary
    file first and renamed, so a failure never leaves half a file."""
    path = Path(path)
    text = rig_yaml(rig, header, notes)
    yaml.safe_load(text)   # a YAML error here is ours, not the user's
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f'.{path.name}.', suffix='.tmp')
    try:
        with os.fdopen(fd, 'w') as fh:
            fh.write(text)
        back = load_rig_file(tmp)
        bad = [f.name for f in dataclasses.fields(Rig)
               if not math.isclose(float(getattr(back, f.name)), float(getattr(rig, f.name)), rel_tol=1e-8)]
        if bad:
            raise ValueError(f'{path}: read back differently: {", ".join(bad)}')
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path
