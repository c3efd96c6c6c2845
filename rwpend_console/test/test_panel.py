"""The gains panel's model: fields from descriptors, values checked before sending, design
previews computed with the controller's own design functions."""
import math

import pytest

from rwpend_console.panel import Field, build_fields, coerce_value, design_preview
from rwpend_control.parameters import DESIGN_DEFAULTS
from rwpend_control.supervisor import gains_from_design
from rwpend_model.rig import load_rig

DESCR = {
    'balance.kpp': {'description': 'gain', 'read_only': False,
                    'floating_point_range': [{'from_value': -1000.0, 'to_value': 0.0, 'step': 0.0}]},
    'status_every': {'description': 'n', 'read_only': False,
                     'integer_range': [{'from_value': 1, 'to_value': 1000, 'step': 1}]},
    'rig.g': {'description': 'rig parameter', 'read_only': True},
    'balance.design.omega0': {'description': 'design', 'read_only': False},
}
VALUES = {'balance.kpp': ('double', -282.0), 'status_every': ('integer', 10), 'rig.g': ('double', 9.81),
          'balance.design.omega0': ('string', '1.5wp'), 'undescribed': ('bool', True)}


def test_fields_from_descriptors():
    fields = {f.name: f for f in build_fields('/rwpend/controller', VALUES, DESCR)}
    kpp = fields['balance.kpp']
    assert (kpp.type, kpp.value, kpp.minimum, kpp.maximum, kpp.step, kpp.group) == \
        ('double', -282.0, -1000.0, 0.0, None, 'balance')
    assert fields['status_every'].minimum == 1 and fields['status_every'].step == 1
    assert fields['rig.g'].read_only and fields['rig.g'].group == 'rig'
    assert fields['balance.design.omega0'].designs == 'balance'
    assert fields['undescribed'].read_only, 'a parameter the node did not describe is not editable'
    order = [f.name for f in build_fields('/n', VALUES, DESCR)]
    assert order.index('balance.design.omega0') < order.index('balance.kpp'), 'design fields first in a group'


def field(type_, read_only=False):
    return Field(node='/n', name='p', type=type_, value=None, read_only=read_only)


@pytest.mark.parametrize('type_, raw, value', [
    ('double', '-300', -300.0), ('double', 2, 2.0), ('double', ' 1e-3 ', 0.001),
    ('integer', '7', 7), ('integer', 7.0, 7), ('bool', 'true', True), ('bool', False, False),
    ('string', '2wp', '2wp'), ('double_array', [1, '2.5'], [1.0, 2.5]), ('string_array', ['a'], ['a']),
])
def test_values_of_the_field_type(type_, raw, value):
    assert coerce_value(field(type_), raw) == value


@pytest.mark.parametrize('type_, raw, why', [
    ('double', 'abc', 'a number'), ('double', 'nan', 'finite'), ('double', True, 'a number'),
    ('double', float('inf'), 'finite'), ('integer', '2.5', 'an integer'), ('bool', 'yes', 'true or false'),
    ('string', 5, 'text'), ('double_array', [], 'non-empty list'), ('byte_array', [1], 'cannot be set'),
])
def test_bad_values_are_refused_with_the_reason(type_, raw, why):
    with pytest.raises(ValueError, match=why):
        coerce_value(field(type_), raw)


def test_read_only_is_refused():
    with pytest.raises(ValueError, match='read-only'):
        coerce_value(field('double', read_only=True), 1.0)


def test_design_preview_is_what_the_controller_designs():
    rig = load_rig()
    designs = {k: v for k, v in DESIGN_DEFAULTS.items() if k.startswith('balance.design.')}
    p = design_preview(rig, 'balance', designs, {'balance.design.omega0': '2wp'})
    expected = gains_from_design(rig, 'balance', {**{k.split('.design.')[1]: v for k, v in designs.items()},
                                                  'omega0': '2wp'})
    assert p.ok and p.gains == expected and p.stable is True and 'stable' in p.reason
    other = design_preview(rig, 'balance', designs, {})
    assert not math.isclose(other.gains['balance.kpp'], p.gains['balance.kpp'])


def test_design_preview_refusals():
    rig = load_rig()
    p = design_preview(rig, 'balance', {}, {'balance.design.omega0': 'fast'})
    assert not p.ok and 'omega' in p.reason
    assert not design_preview(rig, 'nonsense', {}, {}).ok
    assert 'not a design parameter' in design_preview(rig, 'balance', {}, {'balance.kpp': 1}).reason
    w = design_preview(rig, 'wheel', {}, {'wheel.design.omega0': 10.0})
    assert w.ok and w.stable is None and set(w.gains) == {'wheel.kp', 'wheel.ki'}


def _field_of(spec):
    """A field as the console builds it from the descriptor the node's ParameterTable gives
    ``spec`` (rwpend_ros.params.descriptor: range when both bounds, the rest as constraints)."""
    lo, hi = spec.range or (None, None)
    key = 'integer_range' if spec.kind == 'integer' else 'floating_point_range'
    d = {'description': spec.description, 'read_only': spec.read_only,
         'additional_constraints': spec.constraint_text(),
         **({key: [{'from_value': lo, 'to_value': hi, 'step': spec.step}]} if spec.range else {})}
    f, = build_fields('/rwpend/controller', {spec.name: (spec.kind, spec.default)}, {spec.name: d})
    return f


def test_the_controllers_own_specs_judged_before_sending():
    """Every controller parameter: what its spec refuses the panel refuses with the same reason
    (nothing sent), what it takes the panel takes."""
    from rwpend_control.parameters import controller_specs
    from rwpend_ros.paramspec import check
    from rwpend_console.panel import spec_of
    specs = {s.name: s for s in controller_specs(load_rig(), 2)}
    for s in specs.values():
        got = spec_of(_field_of(s))
        assert (got.kind, got.low, got.high, got.low_open, got.high_open, got.choices, got.read_only) == \
            (s.kind, s.low, s.high, s.low_open, s.high_open, s.choices, s.read_only), s.name
    mode = _field_of(specs['mode'])
    assert coerce_value(mode, 'auto') == 'auto'
    with pytest.raises(ValueError) as e:
        coerce_value(mode, 'fly')
    assert str(e.value) == check(specs['mode'], 'fly') and 'one of' in str(e.value)
    every = _field_of(specs['status_every'])
    with pytest.raises(ValueError, match='status_every must be >= 1, got 0'):
        coerce_value(every, '0')
    limit = _field_of(specs['wheel_speed_limit'])
    with pytest.raises(ValueError, match='wheel_speed_limit must be <'):
        coerce_value(limit, str(specs['wheel_speed_limit'].high))
    zeta = _field_of(specs['balance.design.zeta'])
    with pytest.raises(ValueError, match='balance.design.zeta must be > 0'):
        coerce_value(zeta, '0')
    assert coerce_value(_field_of(specs['balance.kpp']), '50') == 50.0, 'stability is the node\'s to judge'


def test_ranges_are_written_for_a_reader():
    """The field's range with its open ends, bounds in 6 significant digits (they were printed
    as raw floats: '1 .. 183.72549019607843'), the other constraints as notes."""
    from rwpend_console.panel import notes_text, range_text
    from rwpend_control.parameters import controller_specs
    rig = load_rig()
    specs = {s.name: s for s in controller_specs(rig, 2)}
    limit = _field_of(specs['wheel_speed_limit'])
    assert range_text(limit) == f'≥ 1 and < {float(rig.omega_max):.6g}'
    assert notes_text(limit) == '', 'the bound of the constraints is in the range'
    assert range_text(_field_of(specs['status_every'])) == '1 .. 1000000'
    assert range_text(_field_of(specs['balance.design.zeta'])) == '> 0'
    assert range_text(_field_of(specs['swingup.design.k_v'])) == '≥ 0'
    cid = _field_of(specs['controller_id'])
    assert (range_text(cid), notes_text(cid)) == ('≥ 0', '< 2^63')
    kpp = _field_of(specs['balance.kpp'])
    assert notes_text(kpp) == 'closed loop (4.8) stable'
    assert notes_text(_field_of(specs['mode'])).startswith('one of: off, ')
    assert range_text(_field_of(specs['mode'])) == ''
    for s in specs.values():
        text = range_text(_field_of(s))
        for number in text.replace('≥', ' ').replace('≤', ' ').replace('>', ' ').replace('<', ' ') \
                .replace('..', ' ').replace('and', ' ').replace(',', ' ').split():
            if number != 'step':
                assert len(number.split('e')[0].lstrip('-').replace('.', '').lstrip('0')) <= 7, (s.name, text)
    fields = {f.name: f for f in build_fields('/rwpend/controller', VALUES, DESCR)}
    assert range_text(fields['balance.kpp']) == '-1000 .. 0'
    assert range_text(fields['rig.g']) == '' and range_text(fields['balance.design.omega0']) == ''
    odd = Field(node='/n', name='p', type='integer', value=4, minimum=0, maximum=100, step=5)
    assert range_text(odd) == '0 .. 100, step 5'
    assert range_text(Field(node='/n', name='p', type='double', value=1.0, constraints='<= 0.30000000000000004')) \
        == '≤ 0.3'


def test_the_page_gets_the_whole_value_and_the_texts():
    fields = {f.name: f.as_dict() for f in build_fields('/rwpend/controller', {
        **VALUES, 'balance.kpp': ('double', -312.34567891234567)}, DESCR)}
    kpp = fields['balance.kpp']
    assert kpp['value_text'] == '-312.34567891234565' and float(kpp['value_text']) == kpp['value']
    assert kpp['range_text'] == '-1000 .. 0' and kpp['notes'] == ''
    assert fields['undescribed']['value_text'] == 'true'
    assert fields['balance.design.omega0']['value_text'] == '1.5wp'
