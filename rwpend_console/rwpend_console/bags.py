"""The bags of the console's folder (pure: files only, no rclpy).

A bag is a directory with a rosbag2 ``metadata.yaml``; the console's analysis writes
``analysis.png`` (``./rwpend analyze --plot``) and ``metrics.json`` (``--json``) beside it, as
the recorder writes ``recording_report.json``.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

import yaml

PLOT = 'analysis.png'
METRICS = 'metrics.json'
_NAME_RE = re.compile(r'[A-Za-z0-9][A-Za-z0-9_.-]{0,99}')
#: metrics shown in the list (rwpend_bag.analysis names), when the analysis has them
SHOWN_METRICS = ('duration_s', 'swing_up_time_s', 'balance_rms_rad', 'control_rms', 'saturation_fraction')


def check_bag_name(name) -> str:
    """A new bag's name: 1-100 characters of A-Z a-z 0-9 _ . -, not starting with . or -."""
    if not isinstance(name, str) or not _NAME_RE.fullmatch(name) or name.endswith('.'):
        raise ValueError('a bag name is 1-100 characters of letters, digits, _ . and -, starting '
                         f'with a letter or digit, got {name!r}')
    return name


def bag_dir(folder: Path, name) -> Path:
    """The directory of bag ``name`` in ``folder`` (ValueError for a bad name)."""
    return Path(folder) / check_bag_name(name)


def _info(meta: dict) -> dict:
    info = meta.get('rosbag2_bagfile_information', {}) if isinstance(meta, dict) else {}
    start = (info.get('starting_time') or {}).get('nanoseconds_since_epoch', 0)
    dur = (info.get('duration') or {}).get('nanoseconds', 0)
    return {'start_ns': int(start or 0), 'duration_s': int(dur or 0) / 1e9,
            'messages': int(info.get('message_count', 0) or 0),
            'topics': len(info.get('topics_with_message_count') or [])}


def describe_bag(path: Path) -> dict | None:
    """One row of the list, or None when ``path`` is not a bag."""
    meta_file = path / 'metadata.yaml'
    if not meta_file.is_file():
        return None
    try:
        row = _info(yaml.safe_load(meta_file.read_text()))
    except (OSError, yaml.YAMLError, TypeError, ValueError, AttributeError) as exc:
        row = {'error': f'unreadable metadata.yaml: {exc}'}
    row['name'] = path.name
    row['size_bytes'] = sum(f.stat().st_size for f in path.iterdir() if f.is_file())
    row['plot'] = (path / PLOT).is_file()
    try:
        metrics = json.loads((path / METRICS).read_text())
        row['metrics'] = {k: metrics[k] for k in SHOWN_METRICS if k in metrics}
    except (OSError, ValueError, TypeError):
        row['metrics'] = None
    return row


def list_bags(folder: Path) -> list[dict]:
    """The bags of ``folder``, newest first ([] when the folder does not exist)."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    rows = [r for r in (describe_bag(p) for p in folder.iterdir() if p.is_dir()) if r is not None]
    rows.sort(key=lambda r: (r.get('start_ns', 0), r['name']), reverse=True)
    return rows


def plot_file(folder: Path, name) -> Path:
    """The analysis plot of bag ``name``; ValueError when the name is bad or there is none."""
    f = bag_dir(folder, name) / PLOT
    if not f.is_file():
        raise ValueError(f'bag {name!r} has no analysis plot yet')
    return f
