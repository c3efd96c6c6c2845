"""Rigs on the console's domains (pure).

A rig is a namespace with the loop's topics (``<ns>/encoders``, ``<ns>/controller/status``)
on one ROS domain; the console names it ``<domain>:<namespace>`` (``60:/rwpend``) -- two rigs
of one lab differ in the domain id, the namespace or both.
"""
from __future__ import annotations

import re
from typing import Iterable

#: topics whose presence makes a namespace a rig
RIG_TOPICS = ('/encoders', '/controller/status')
_NS_RE = re.compile(r'(/[A-Za-z][A-Za-z0-9_]*)+|/')


def rig_namespaces(topics: Iterable[str]) -> list[str]:
    """Namespaces that publish a rig's topics, sorted."""
    out = set()
    for t in topics:
        for suffix in RIG_TOPICS:
            if t.endswith(suffix):
                ns = t[:-len(suffix)] or '/'
                if _NS_RE.fullmatch(ns):
                    out.add(ns)
    return sorted(out)


def rig_id(domain: int, ns: str) -> str:
    return f'{domain}:{ns}'


def parse_rig_id(text: str, domains: Iterable[int]) -> tuple[int, str]:
    """'60:/rwpend' -> (60, '/rwpend'); ValueError with the reason (malformed, a domain the
    console does not watch)."""
    domain, sep, ns = (text or '').partition(':')
    if not sep or not domain.isdigit() or not _NS_RE.fullmatch(ns):
        raise ValueError(f'a rig is DOMAIN:/NAMESPACE (e.g. 0:/rwpend), got {text!r}')
    d = int(domain)
    watched = sorted(set(domains))
    if d not in watched:
        raise ValueError(f'this console does not watch domain {d} (it watches '
                         f'{", ".join(map(str, watched))}; ./rwpend console --domain {d})')
    return d, ns


def node_name(ns: str, node: str) -> str:
    """The fully qualified name of a rig's node: ('/rwpend', 'controller') -> '/rwpend/controller';
    an absolute ``node`` stays; ValueError for a name that is not a node name."""
    if node.startswith('/'):
        full = node
    else:
        full = f'{ns.rstrip("/")}/{node}'
    if not re.fullmatch(r'(/[A-Za-z_][A-Za-z0-9_]*)+', full):
        raise ValueError(f'not a node name: {node!r}')
    return full
