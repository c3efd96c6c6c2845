"""Message definitions for bags, the standard ROS 2 way (no rclpy).

* :func:`joined_definition` builds the ``ros2msg`` schema text rosbag2 embeds in MCAP: the main
  ``.msg`` text, then for every dependency a line of 80 ``=``, ``MSG: pkg/Name`` and its text.
  ``.msg`` files are looked up under ``<prefix>/share/<pkg>/msg/`` for every prefix of
  ``$AMENT_PREFIX_PATH`` (then ``sys.prefix``) and parsed by rosbags, both by
  :mod:`rwpend_ros.msglayout` (the source of the wire codecs' layouts too).
* :func:`type_hash` computes the RIHS01 type description hash (rosbags, equal to rosidl's).
* :func:`import_message_class` resolves ``pkg/msg/Name`` to the Python class (for rclpy).
"""
from __future__ import annotations

import functools
import importlib

from rwpend_ros.msglayout import (DefinitionNotFound, dependencies, fields, full_type, msg_text,  # noqa: F401
                                  parse, share_dirs, split_type)

SEPARATOR = '=' * 80


def field_types(text: str, pkg: str) -> list[str]:
    """Message types ('pkg/Name') the fields of a .msg text of package ``pkg`` use, in order,
    each once (rosbags parses it; constants are not fields)."""
    name = f'{pkg}/msg/Definition'
    return ['/'.join(split_type(t)) for t in dependencies(parse(text, name)[name])]


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
        todo.extend('/'.join(split_type(t)) for t in dependencies(fields(dep)))
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
