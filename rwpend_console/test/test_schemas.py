"""The bridge's schemas: joined ros2msg definitions that decode the CDR the nodes publish."""
import pytest

from rwpend_bag.msgdefs import DefinitionNotFound
from rwpend_console.schemas import message_schema, service_schemas, split_srv
from rwpend_console.wsclient import decode, encode, message_class


def test_message_schema_decodes_what_rclpy_serializes():
    from rclpy.serialization import serialize_message
    from rwpend_msgs.msg import StateEstimate
    s = message_schema('rwpend_msgs/msg/StateEstimate')
    assert s.name == 'rwpend_msgs/msg/StateEstimate' and 'MSG: std_msgs/Header' in s.text
    m = StateEstimate(seq=7, theta=3.0, theta_dot=-0.5, estimator='observer3')
    m.header.stamp.sec, m.header.frame_id = 12, 'rwpend'
    out = decode(s.name, s.text, serialize_message(m))
    assert (out.seq, out.theta, out.theta_dot, out.estimator, out.header.stamp.sec, out.header.frame_id) == \
        (7, 3.0, -0.5, 'observer3', 12, 'rwpend')


def test_service_schemas_round_trip_through_rclpy():
    from rclpy.serialization import deserialize_message, serialize_message
    from rwpend_msgs.srv import Disturb
    s = service_schemas('rwpend_msgs/srv/Disturb')
    assert (s.request.name, s.response.name) == ('rwpend_msgs/srv/Disturb_Request', 'rwpend_msgs/srv/Disturb_Response')
    assert 'float64 magnitude' in s.request.text and 'bool success' in s.response.text
    req_cls = message_class(s.request.name, s.request.text)
    payload = encode(s.request.name, s.request.text, req_cls(kind=0, magnitude=0.5, duration=0.0))
    req = deserialize_message(payload, Disturb.Request)
    assert (req.kind, req.magnitude) == (0, 0.5)
    resp = decode(s.response.name, s.response.text, serialize_message(Disturb.Response(success=True, message='ok')))
    assert resp.success and resp.message == 'ok'
    empty = service_schemas('std_srvs/srv/Trigger').request
    assert empty.text.strip() == ''


def test_bad_types():
    with pytest.raises(ValueError, match='pkg/srv/Name'):
        service_schemas('rwpend_msgs/msg/SetMode')
    with pytest.raises(DefinitionNotFound):
        service_schemas('nopkg/srv/Nothing')
    with pytest.raises(ValueError, match='---'):
        split_srv('int32 a\n')
