"""Schemas the bridge advertises (pure: the installed .msg/.srv files, no rclpy).

Topics go out as their CDR bytes with a ``ros2msg`` schema -- the full joined definition, as
rosbag2 embeds it in MCAP (:func:`rwpend_bag.msgdefs.joined_definition`); a service's request
and response each get theirs, named ``pkg/srv/Name_Request`` / ``_Response`` as Foxglove's own
ROS 2 bridge names them.
"""
from __future__ import annotations

import functools
import re
from dataclasses import dataclass

from rwpend_bag.msgdefs import DefinitionNotFound, join_definition, joined_definition, share_dirs

MESSAGE_ENCODING = 'cdr'
SCHEMA_ENCODING = 'ros2msg'
_SRV_RE = re.compile(r'^([A-Za-z]\w*)/srv/([A-Za-z]\w*)$')


@dataclass(frozen=True)
class MessageSchema:
    name: str        # pkg/msg/Name
    text: str        # the joined ros2msg definition


@dataclass(frozen=True)
class ServiceSchemas:
    type: str        # pkg/srv/Name
    request: MessageSchema
    response: MessageSchema


def message_schema(type_name: str) -> MessageSchema:
    """The schema of a topic's type ('pkg/msg/Name'); DefinitionNotFound / ValueError."""
    return MessageSchema(type_name, joined_definition(type_name))


def split_srv(text: str) -> tuple[str, str]:
    """A .srv text -> (request part, response part) at its ``---`` line."""
    lines = text.splitlines()
    for i, line in enumerate(lines):
        if line.strip() == '---':
            return '\n'.join(lines[:i]) + '\n', '\n'.join(lines[i + 1:]) + '\n'
    raise ValueError('not a .srv definition (no --- line)')


@functools.lru_cache(maxsize=None)
def service_schemas(srv_type: str) -> ServiceSchemas:
    """The request and response schemas of 'pkg/srv/Name' (from ``share/pkg/srv/Name.srv``)."""
    m = _SRV_RE.match(srv_type)
    if not m:
        raise ValueError(f'not a service type: {srv_type!r} (expected pkg/srv/Name)')
    pkg, name = m.groups()
    for share in share_dirs():
        f = share / pkg / 'srv' / f'{name}.srv'
        if f.is_file():
            req, resp = split_srv(f.read_text(encoding='utf-8'))
            return ServiceSchemas(srv_type, MessageSchema(f'{srv_type}_Request', join_definition(req, pkg)),
                                  MessageSchema(f'{srv_type}_Response', join_definition(resp, pkg)))
    raise DefinitionNotFound(f'no {pkg}/srv/{name}.srv under any of {", ".join(map(str, share_dirs()))}')
