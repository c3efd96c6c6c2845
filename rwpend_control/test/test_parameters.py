"""The controller's one parameter table (pure): the config, the declarations and the validation
all come from it."""
from __future__ import annotations

from dataclasses import fields, replace

from rwpend_control.parameters import (BY_NAME, CONFIG_PARAMS, DESIGN_DEFAULTS, DESIGN_GROUPS, DESIGNED,
                                       PARAMS, controller_specs, range_refusal, type_refusal)
from rwpend_control.supervisor import ControllerConfig, validate_config
from rwpend_model.rig import load_rig

rig = load_rig()


def test_the_config_has_one_field_per_config_row_with_its_default():
    assert [f.name for f in fields(ControllerConfig)] == [p.field for p in CONFIG_PARAMS]
    cfg = ControllerConfig()
    assert all(getattr(cfg, p.field) == p.default for p in CONFIG_PARAMS)
    assert validate_config(cfg, rig) == [] and validate_config(ControllerConfig.designed(rig), rig) == []


def test_each_row_is_declared_once_with_its_range_for_the_rig():
    specs = {s.name: s for s in controller_specs(rig, 7)}
    assert set(specs) == {p.name for p in PARAMS} | {'thread_priority'} and len(PARAMS) == len(BY_NAME)
    assert specs['state_queue_depth'].default == 7
    assert {n for n, s in specs.items() if s.read_only} == {
        'state_queue_depth', 'controller_id', 'law.file', 'law.params', 'thread_priority'}
    for name in DESIGNED:                    # designed at start unless given
        assert specs[name].default is None and specs[name].kind == 'double'
    assert DESIGNED == {n for names in DESIGN_GROUPS.values() for n in names}
    assert set(DESIGN_DEFAULTS) == {n for n in specs if '.design.' in n}
    # a bound that is a function of the rig
    slow = replace(rig, sample_period=2 * rig.sample_period)
    slow_specs = {s.name: s for s in controller_specs(slow, 5)}
    assert slow_specs['max_saturation_time'].low == 2 * rig.sample_period
    assert specs['wheel_speed_limit'].range == (1.0, rig.omega_max) and specs['wheel_speed_limit'].high_open


def test_a_value_is_judged_by_its_row():
    p = BY_NAME
    assert type_refusal(p['catch_region'], 1) == 'catch_region must be a bool, got 1'
    assert type_refusal(p['state_timeout_samples'], 2.0) == 'state_timeout_samples must be an integer, got 2.0'
    assert type_refusal(p['saturation_action'], 'on').startswith('saturation_action must be one of off, ')
    assert type_refusal(p['theta_s'], float('nan')) == 'theta_s must be finite, got nan'
    assert range_refusal(p['theta_s'], 4.0, rig) == 'theta_s = 4 out of range [0.001, 3.14159]'
    assert range_refusal(p['wheel_speed_limit'], rig.omega_max, rig).startswith(
        f'wheel_speed_limit = {rig.omega_max:g} rad/s must be in [1, ')
    assert range_refusal(p['wheel_speed_limit'], 750.0, rig) == ''
    errors = validate_config(replace(ControllerConfig(), theta_s=4.0, wheel_ki=2.0), rig)
    assert errors == ['wheel.ki = 2 out of range [0, 1]', 'theta_s = 4 out of range [0.001, 3.14159]']
