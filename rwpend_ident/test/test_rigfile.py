"""The written rig YAML (the format of rwpend_model/config/rig.yaml) and the split of the model
parameters into physical data (no ROS)."""
from __future__ import annotations

import dataclasses

import pytest
import yaml

from rwpend_ident.models import IDENTIFIED, model_values, rig_from_model
from rwpend_ident.rigfile import example_rig_file, format_value, write_rig
from rwpend_model.rig import load_rig, load_rig_file, read_params_file

HEAVY_RIG = example_rig_file()


def test_numbers_stay_numbers_for_every_yaml_reader():
    for v in (1e-05, 2.495e-05, 0.0005, 60.0, 0.0, 9.81, 500, 4000):
        assert yaml.safe_load(f'x: {format_value(v)}')['x'] == v


def test_written_file_loads_as_the_same_rig_and_has_every_key(tmp_path):
    rig = load_rig_file(HEAVY_RIG)
    path = write_rig(tmp_path / 'rig.yaml', rig, header=['identified'], notes={'m_p': 'identified: +- 0.001'})
    assert load_rig_file(path) == rig
    params = read_params_file(path, '/rwpend/controller')
    assert {k[4:] for k in params} == {f.name for f in dataclasses.fields(rig)}
    text = path.read_text()
    assert text.startswith('# identified\n/**:\n  ros__parameters:\n    rig:\n')
    assert 'identified: +- 0.001' in text
    assert not list(tmp_path.glob('.rig.yaml*')), 'no temporary file left'


def test_the_split_keeps_the_measured_lengths_and_recovers_the_masses():
    """With l_p, l_r, m_r, g, k_u of the base rig, a, b_p, b_r give back m_p, J_p, J_r (2.3), (2.15)."""
    base = load_rig()
    heavy = load_rig_file(HEAVY_RIG)
    rig = rig_from_model(base, model_values(heavy))
    for k in ('m_p', 'j_p', 'j_r', *IDENTIFIED):
        assert getattr(rig, k) == pytest.approx(getattr(heavy, k), rel=1e-9), k


def test_the_simulation_split_has_the_same_model():
    base = load_rig()
    values = dict(model_values(base), a=90.0, b_p=0.7)
    sim = rig_from_model(base, values, physical=False)
    for k in ('a', 'b_p', 'b_r'):
        assert getattr(sim, k) == pytest.approx(values[k], rel=1e-12)


def test_an_impossible_split_is_refused_with_the_reason():
    base = load_rig()
    with pytest.raises(ValueError, match='cannot be split into physical data .* J_p'):
        rig_from_model(base, dict(model_values(base), a=base.a * 1.5))
