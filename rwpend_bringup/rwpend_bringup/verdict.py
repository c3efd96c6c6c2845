"""The verdict of a run of ``./rwpend up`` (pure: no rclpy): did the loop live to the end, and
does the bag hold the run? A run whose loop was dead at the end, or whose bag is much shorter
than the run, ends with a non-zero exit status and the reason -- never silently."""
from __future__ import annotations

from rwpend_ros.health import EXIT_LOOP_DEAD

#: a bag holding less than this share of the run's samples is "much shorter than the run"
MIN_SHARE = 0.9
#: exit status of ``./rwpend up`` when the bag is much shorter than the run
EXIT_SHORT_BAG = 4
#: wall seconds a real-time stack takes before its first sample (processes, discovery, start.delay)
START_UP_S = 5.0


def expected_samples(h: float, duration: float | None, lockstep: bool, wall_s: float,
                     interrupted: bool = False) -> int | None:
    """The plant samples a run's bag should hold (None: not judged). ``--duration`` is counted by
    the plant (from sample 0 in the simulator, from the first command in the driver), so a run
    that ended by itself holds ``duration / h``; a real-time run without one, or stopped by a
    signal (``interrupted``, Ctrl-C) before it, what its wall time allows after
    :data:`START_UP_S`; a lockstep run stopped by a signal is not judged (its simulated length is
    the plant's, unknown to ``up``)."""
    by_duration = round(duration / h) if duration else None
    by_wall = round((wall_s - START_UP_S) / h) if not lockstep and wall_s > 2 * START_UP_S else None
    if not interrupted:
        return by_duration or by_wall
    if by_duration and by_wall:
        return min(by_duration, by_wall)
    return by_wall


def dead_nodes(exit_codes: dict[str, int]) -> list[str]:
    """The processes that ended with :data:`EXIT_LOOP_DEAD` (their reason is in their log)."""
    return sorted(n for n, c in exit_codes.items() if c == EXIT_LOOP_DEAD)


def recording_problems(report: dict, expected_samples: int | None) -> tuple[list[str], list[str]]:
    """(problems, warnings) of a bag's ``recording_report.json`` (rwpend_bag.writer): a problem
    when the plant's samples in the bag (the ``EncoderCounts`` topic) are fewer than
    :data:`MIN_SHARE` of ``expected_samples`` (None: not judged), or when the writer failed; a
    warning per loop topic that lost messages (gaps in its seq), with how many."""
    problems, warnings = [], []
    if report.get('writer_error'):
        problems.append(f"the bag writer failed: {report['writer_error']}")
    topics = report.get('topics', {})
    encoders = [name for name in topics if name.endswith('/encoders')]
    if expected_samples:
        got = max((topics[n].get('received', 0) for n in encoders), default=0)
        if got < MIN_SHARE * expected_samples:
            problems.append(f'the bag holds {got} of the run\'s {expected_samples} samples '
                            f'({100 * got / expected_samples:.1f} %): much shorter than the run')
    for name, t in sorted(topics.items()):
        missing = t.get('missing', 0)
        if missing:
            warnings.append(f'{name}: {missing} message(s) missing in {t.get("gap_count", 0)} gap(s)')
    return problems, warnings
