"""Diagnostics as every node publishes them: one DiagnosticStatus in a DiagnosticArray, packed
as wire bytes."""
from __future__ import annotations

from typing import Any, Iterable, Mapping

from rwpend_ros import wire

def publish_diagnostic(pub, stamp_ns: int, name: str, hardware_id: str, level, message: str,
                       values: Mapping[str, Any] | Iterable[tuple[str, Any]] = ()) -> None:
    """One DiagnosticStatus (``level``: ``DiagnosticStatus.OK`` / ``WARN`` / ``ERROR`` / ``STALE``
    or 0-3; ``values``: key-values, each turned into text with ``str()``) in a DiagnosticArray
    stamped ``stamp_ns``, published as wire bytes (:func:`rwpend_ros.wire.pack_diagnostic_array`),
    without building the message as rclpy objects (PERFORMANCE.md, "What each mechanism buys")."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    pub.publish(wire.pack_diagnostic_array(sec, nanosec, [(level, name, message, hardware_id, values)]))


def stamp_to_ns(stamp) -> int:
    """builtin_interfaces/Time -> integer nanoseconds."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec
