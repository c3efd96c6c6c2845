"""ROS parameters as the Foxglove protocol names and types them."""
import pytest

from rwpend_console.foxglove_params import from_wire, join_name, split_name, to_wire


def test_names():
    assert split_name('/rwpend/controller.balance.kpp') == ('/rwpend/controller', 'balance.kpp')
    assert join_name('/rwpend/controller', 'mode') == '/rwpend/controller.mode'
    for bad in ('controller.mode', '/rwpend/controller', '/rwpend/controller.', '/a b.c', ''):
        with pytest.raises(ValueError, match='/NAMESPACE/NODE.PARAMETER'):
            split_name(bad)


def test_values_and_hints():
    assert to_wire('double', 2) == (2.0, 'float64')
    assert to_wire('double_array', [1, 2]) == ([1.0, 2.0], 'float64_array')
    assert to_wire('integer', 3) == (3, None)
    assert to_wire('string', 'auto') == ('auto', None)
    assert to_wire('byte_array', [b'a', b'b']) == (b'ab', 'byte_array')


def test_values_from_a_client_are_checked_like_the_page():
    assert from_wire('/n', 'balance.kpp', 'double', False, -300) == -300.0
    with pytest.raises(ValueError, match='read-only'):
        from_wire('/n', 'rig.g', 'double', True, 9.9)
    with pytest.raises(ValueError, match='a number'):
        from_wire('/n', 'balance.kpp', 'double', False, 'soft')
    with pytest.raises(ValueError, match='cannot be unset'):
        from_wire('/n', 'mode', 'string', False, None)
