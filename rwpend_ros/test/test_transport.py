"""rwpend_ros.transport: which Fast DDS transport the processes get (pure: environment only)."""
import xml.etree.ElementTree as ET

import pytest

from rwpend_ros.transport import PROFILE, SUBNET_PROFILE, apply_transport, discovery_range, transport_choice


def test_localhost_becomes_udp_profile():
    env = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    assert 'udp' in apply_transport(env)
    assert env['FASTRTPS_DEFAULT_PROFILES_FILE'] == str(PROFILE)
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'SYSTEM_DEFAULT'
    assert discovery_range(env) == 'LOCALHOST'
    before = dict(env)
    apply_transport(env)                      # a child process applies it again: no change
    assert env == before


@pytest.mark.parametrize('rng', ['SUBNET', ''])
def test_subnet_gets_the_udp_subnet_profile(rng):
    env = {'ROS_AUTOMATIC_DISCOVERY_RANGE': rng} if rng else {}
    apply_transport(env)
    assert env['FASTRTPS_DEFAULT_PROFILES_FILE'] == str(SUBNET_PROFILE) and SUBNET_PROFILE.is_file()
    assert 'FASTDDS_BUILTIN_TRANSPORTS' not in env
    assert env.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '') == rng, 'discovery stays rmw_fastrtps\'s'
    assert discovery_range(env) == (rng or 'SUBNET')
    before = dict(env)
    apply_transport(env)                      # a child process applies it again: no change
    assert env == before


def test_subnet_profile_is_udp_with_big_buffers():
    ns = {'d': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}
    root = ET.parse(SUBNET_PROFILE).getroot()
    assert root.find('.//d:transport_descriptor/d:type', ns).text == 'UDPv4'
    assert int(root.find('.//d:transport_descriptor/d:receiveBufferSize', ns).text) >= 4 << 20
    assert root.find('.//d:useBuiltinTransports', ns).text == 'false'
    assert root.find('.//d:data_writer', ns) is None, "Fast DDS's writer timing (see the file)"


@pytest.mark.parametrize('extra', [
    {'RWPEND_TRANSPORT': 'shm'},
    {'FASTRTPS_DEFAULT_PROFILES_FILE': '/etc/mine.xml'},
    {'FASTDDS_BUILTIN_TRANSPORTS': 'SHM'},
    {'ROS_STATIC_PEERS': '192.168.1.7'},
    {'RMW_IMPLEMENTATION': 'rmw_cyclonedds_cpp'},
])
def test_user_configuration_is_left_alone(extra):
    env = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', **extra}
    before = dict(env)
    apply_transport(env)
    assert env == before


def test_off_range_untouched_and_bad_choice_refused():
    env = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'OFF'}
    apply_transport(env)
    assert env == {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'OFF'}
    env = {'RWPEND_TRANSPORT': 'carrier-pigeon', 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    with pytest.raises(ValueError, match='RWPEND_TRANSPORT'):
        apply_transport(env)
    assert env == {'RWPEND_TRANSPORT': 'carrier-pigeon', 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}


def test_profile_is_udp_on_loopback_only():
    ns = {'d': 'http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles'}
    root = ET.parse(PROFILE).getroot()
    t = root.find('.//d:transport_descriptor', ns)
    assert t.find('d:type', ns).text == 'UDPv4'
    assert [a.text for a in t.findall('.//d:interfaceWhiteList/d:address', ns)] == ['127.0.0.1']
    p = root.find(".//d:participant[@is_default_profile='true']", ns)
    assert p.find('.//d:useBuiltinTransports', ns).text == 'false'
    assert p.find('.//d:initialPeersList//d:address', ns).text == '127.0.0.1'
    assert p.find('.//d:metatrafficMulticastLocatorList', ns) is None


def test_entry_point_exits_2_with_a_message(capsys):
    from rwpend_ros.transport import apply_transport_or_exit
    with pytest.raises(SystemExit) as exc:
        apply_transport_or_exit({'RWPEND_TRANSPORT': 'tcp'})
    assert exc.value.code == 2
    assert 'RWPEND_TRANSPORT' in capsys.readouterr().err


def test_transport_choice():
    assert transport_choice({}) == 'udp'
    assert transport_choice({'RWPEND_TRANSPORT': ' SHM '}) == 'shm'
    with pytest.raises(ValueError, match='expected one of udp, shm'):
        transport_choice({'RWPEND_TRANSPORT': 'tcp'})
