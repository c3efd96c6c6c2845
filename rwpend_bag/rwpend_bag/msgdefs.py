"""Message definitions for bags, the standard ROS 2 way (no rclpy).

* :func:`joined_definition` builds the ``ros2msg`` schema text rosbag2 embeds in MCAP: the main
  ``.msg`` text, then for every dependency a line of 80 ``=``, ``MSG: pkg/Name`` and its text.
  ``.msg`` files are looked up under ``<prefix>/share/<pkg>/msg/`` for every prefix of
  ``$AMENT_PREFIX_PATH`` (then ``sys.prefix``).
* :func:`type_hash` computes the RIHS01 type description hash (rosbags, equal to rosidl's).
* :func:`import_message_class` resolves ``pkg/msg/Name`` to the Python class (for rclpy).
"""
from __future__ import annotations

import functools
import importlib
import os
import re
import sys
from pathlib import Path

SEPARATOR = '=' * 80
PRIMITIVES = {'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
              'int32', 'uint32', 'int64', 'uint64', 'string', 'wstring'}


class DefinitionNotFound(LookupError):
    """No .msg file for a type name."""


def split_type(type_name: str) -> tuple[str, str]:
    """'pkg/msg/Name' or 'pkg/Name' -> ('pkg', 'Name')."""
    parts = type_name.strip().split('/')
    if len(parts) == 3 and parts[1] == 'msg':
        return parts[0], parts[2]
    if len(parts) == 2:
        return parts[0], parts[1]
    raise ValueError(f'not a message type name: {type_name!r} (expected pkg/msg/Name)')


def full_type(type_name: str) -> str:
    pkg, name = split_type(type_name)
    return f'{pkg}/msg/{name}'


def share_dirs() -> list[Path]:
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    prefixes += [sys.prefix]
    out, seen = [], set()
    for p in prefixes:
        d = Path(p) / 'share'
        if d not in seen:
            seen.add(d)
            out.append(d)
    return out


@functools.lru_cache(maxsize=None)
def msg_text(type_name: str) -> str:
    """Text of the .msg file of a type."""
    pkg, name = split_type(type_name)
    for share in share_dirs():
        f = share / pkg / 'msg' / f'{name}.msg'
        if f.is_file():
            return f.read_text(encoding='utf-8')
    raise DefinitionNotFound(f'no {pkg}/msg/{name}.msg under any of '
                             f'{", ".join(str(s) for s in share_dirs())}')


_FIELD = re.compile(r'^\s*([A-Za-z][\w/]*)(<=\d+)?(\[[^\]]*\])?\s+([A-Za-z]\w*)\s*(=)?')


def field_types(text: str, pkg: str) -> list[str]:
    """Non-primitive field types ('pkg/Name') referenced by a .msg text, in order; constants skipped."""
    out = []
    for line in text.splitlines():
        line = line.split('#', 1)[0].strip()
        if not line:
            continue
        m = _FIELD.match(line)
        if not m or m.group(5):  # not a field, or a constant NAME=value
            continue
        base = m.group(1)
        if base in PRIMITIVES:
            continue
        if base == 'Header':
            dep = 'std_msgs/Header'
        elif '/' in base:
            dep = '/'.join(split_type(base))
        else:
            dep = f'{pkg}/{base}'
        out.append(dep)
    return out


@functools.lru_cache(maxsize=None)
def joined_definition(type_name: str) -> str:
    """The full ros2msg definition of a type with all its dependencies (as rosbag2 writes it)."""
    pkg, _ = split_type(type_name)
    return join_definition(msg_text(type_name), pkg)


def join_definition(main: str, pkg: str) -> str:
    """``main`` (a .msg text, or one part of a .srv, of package ``pkg``) followed by the
    definitions of every type it uses, as :func:`joined_definition` writes them."""
    order: list[str] = []
    todo = field_types(main, pkg)
    while todo:
        dep = todo.pop(0)
        if dep in order:
            continue
        order.append(dep)
        dpkg, _ = split_type(dep)
        todo.extend(field_types(msg_text(dep), dpkg))
    parts = [main.rstrip('\n')]
    for dep in order:
        parts.append(f'{SEPARATOR}\nMSG: {dep}\n{msg_text(dep).rstrip(chr(10))}')
    return '\n'.join(parts) + '\n'


@functools.lru_cache(maxsize=None)
def type_hash(type_name: str, definition: str | None = None) -> str:
    """RIHS01 hash of a type from its joined definition ('' when it cannot be computed)."""
    try:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore
        store = get_typestore(Stores.EMPTY)
        store.register(get_types_from_msg(definition or joined_definition(type_name),
                                          full_type(type_name)))
        return store.hash_rihs01(full_type(type_name))
    except Exception:  # noqa: BLE001 - a hash is optional metadata
        return ''


def import_message_class(type_name: str):
    """'pkg/msg/Name' -> the Python message class. Raises ImportError with a clear message."""
    pkg, name = split_type(type_name)
    try:
        module = importlib.import_module(f'{pkg}.msg')
        return getattr(module, name)
    except (ImportError, AttributeError) as exc:
        raise ImportError(f'message type {type_name} is not importable here ({exc})') from exc
