"""Every file, module and document section that the documents and the code name exists.

Read: README.md, PERFORMANCE.md, docs/*.md, the packages' *.md files, the Python sources, the
``rwpend`` script and the Makefile. Checked (text only: nothing is imported, no ROS):

* markdown links ``[text](path#anchor)`` (relative to the document);
* repository paths in prose, code spans and code blocks: ``a/b/c.ext`` whose first folder is a
  top-level entry of the repository (or an entry beside the document); a package-relative path
  ``rwpend_x/y.py`` stands for ``rwpend_x/rwpend_x/y.py``;
* Python modules ``rwpend_x.y[.name]`` (the module's file, and ``name`` in it);
* sections: ``PERFORMANCE.md, "Title"``, ``README, "Title"``, ``docs/x.md, "Title"`` (a heading
  that is, or starts with, the title), ``FILE.md#anchor`` (a heading's GitHub anchor or an
  explicit ``<a id=...>``), ``PERFORMANCE.md, 13.`` / ``section 13`` (a numbered heading);
* ``git show SHA:PATH``: a commit of the history that holds the path.
"""
from __future__ import annotations

import re
import subprocess
from functools import lru_cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Known-dangling references (file, exact text) tolerated while they are being fixed: none.
ALLOWED: set = set()

#: folders that builds and runs make (git-ignored): paths into them are outputs, not references
GENERATED = {'build', 'install', 'log', 'demo_out', 'bench_out', 'soak_out', 'console_out',
             'lab_out', 'lab_report', 'id_out', 'sweep_out', 'node_modules'}
SKIP_DIRS = GENERATED | {'__pycache__', 'resource', 'static', 'templates'}
FILE_EXT = {'so', 'py', 'md', 'yaml', 'yml', 'json', 'html', 'png', 'svg', 'csv', 'parquet', 'xml',
            'txt', 'msg', 'srv', 'c', 'h', 'sh', 'elf', 'bin', 'hex', 'map', 'mcap', 'db3'}

PATH_RE = re.compile(r'(?<![\w/.:$~-])((?:\.\./)*[A-Za-z0-9_][A-Za-z0-9_.-]*(?:/[A-Za-z0-9_.-]+)+/?)')
MODULE_RE = re.compile(r'(?<![\w./-])(rwpend_\w+(?:\.[A-Za-z_]\w*)+)')
LINK_RE = re.compile(r'\[[^\]\n]*\]\(([^)\s]+)\)')
SECTION_RE = re.compile(
    r'(?<![\w/.-])((?:[\w.-]+/)*(?:README|PERFORMANCE|[\w-]+\.md))(?:\.md)?,?[ \t]+'
    r'"([^"\n]+(?:\n[ \t]*#?[ \t]*[^"\n]+)?)"')
NUMBERED_RE = re.compile(r'(?<![\w/.-])((?:[\w.-]+/)*[\w-]+\.md),?[ \t]+(?:section[ \t]+)?(\d+)\.?(?![\w%])')
ANCHOR_RE = re.compile(r'(?<![\w/.-])((?:[\w.-]+/)*[\w-]+\.md)#([\w-]+)')
GIT_SHOW_RE = re.compile(r'git show ([0-9a-f]{7,40}):([\w./-]+)')


@lru_cache(maxsize=None)
def _tracked_top() -> frozenset[str]:
    """The repository's top-level entries: not hidden, not what builds and runs make (outputs,
    Python's bytecode cache)."""
    return frozenset({p.name for p in ROOT.iterdir()
            if not p.name.startswith('.') and p.name not in GENERATED | {'__pycache__'}
            and not p.name.endswith('_out')})


def documents() -> list[Path]:
    docs = [ROOT / 'README.md', ROOT / 'PERFORMANCE.md', *sorted((ROOT / 'docs').glob('*.md'))]
    docs += sorted(p for p in ROOT.glob('*/*.md') if p.parent.name not in SKIP_DIRS | {'docs'})
    return [p for p in docs if p.exists()]


def sources() -> list[Path]:
    out = [ROOT / 'rwpend', ROOT / 'Makefile']
    for top in sorted(_tracked_top()):
        base = ROOT / top
        if base.is_dir():
            out += [p for p in sorted(base.rglob('*.py'))
                    if not (set(p.relative_to(ROOT).parts) & SKIP_DIRS)
                    and not any(part.endswith('.egg-info') for part in p.parts)]
    return [p for p in out if p.exists() and p != Path(__file__).resolve()]


# ------------------------------------------------------------------ headings and anchors
def _slug(text: str) -> str:
    text = re.sub(r'<[^>]+>', '', text).strip().lower()
    text = re.sub(r'[^\w\- ]', '', text)
    return text.replace(' ', '-')


def _plain(text: str) -> str:
    return re.sub(r'\s+', ' ', re.sub(r'[`*_]', '', text)).strip().lower()


@lru_cache(maxsize=None)
def headings(path: Path) -> tuple[tuple[str, ...], frozenset[str]]:
    """(the headings' plain text, their anchors) of a markdown file."""
    titles, anchors, seen, fence = [], set(), {}, False
    for line in path.read_text(encoding='utf-8').splitlines():
        if line.lstrip().startswith(('```', '~~~')):
            fence = not fence
            continue
        anchors.update(re.findall(r'<a\s+(?:id|name)="([^"]+)"', line))
        m = re.match(r'#{1,6}\s+(.*?)\s*#*\s*$', line)
        if m and not fence:
            titles.append(_plain(m.group(1)))
            slug = _slug(m.group(1))
            n = seen.get(slug, 0)
            seen[slug] = n + 1
            anchors.add(slug if n == 0 else f'{slug}-{n}')
    return tuple(titles), frozenset(anchors)


def _has_section(path: Path, title: str) -> bool:
    want = _plain(title)
    return any(t == want or (t.startswith(want) and not t[len(want)].isalnum())
               for t in headings(path)[0])


# ------------------------------------------------------------------ resolution
@lru_cache(maxsize=None)
def _resolve(ref: str, here: Path) -> Path | None:
    """The existing file or folder a repository path names, from a file in folder ``here``."""
    ref = ref.rstrip('/')
    first = ref.split('/')[0]
    candidates = [here / ref, ROOT / ref]
    if first.startswith('rwpend_'):
        candidates.append(ROOT / first / ref)            # package-relative: rwpend_x/y.py
    if first == 'rwpend_msgs':                    # a type name (rwpend_msgs/msg/X) or rosidl's output
        stem = re.sub(r'(_Request|_Response)?(\.\w+)?$', '', ref.split('/')[-1])
        candidates += [ROOT / first / kind / f'{stem}.{kind}' for kind in ('msg', 'srv')]
    for c in candidates:
        if c.exists():
            return c
    return None


def _is_repo_path(ref: str, here: Path) -> bool:
    first = ref.split('/')[0]
    if first in ('.', '..'):          # a relative path is one of ours only if it lands in a tracked folder
        target = (here / ref).resolve()
        return target.is_relative_to(ROOT) and target != ROOT \
            and target.relative_to(ROOT).parts[0] in _tracked_top()
    if any(part in GENERATED or part.endswith('_out') for part in ref.split('/')):
        return False
    return first in _tracked_top() or (here != ROOT and (here / first).exists()
                                       and first not in GENERATED)


@lru_cache(maxsize=None)
def _module_text(path: Path) -> str:
    return path.read_text(encoding='utf-8', errors='replace')


@lru_cache(maxsize=None)
def _module_exists(name: str) -> bool:
    parts = name.split('.')
    pkg = ROOT / parts[0]
    if parts[-1] in FILE_EXT or parts[-1].startswith('__'):
        return True                                       # a file name such as rwpend_fw.so
    if not pkg.is_dir():
        return False
    if parts[0] == 'rwpend_msgs':                         # generated: rwpend_msgs.msg.EncoderCounts
        if len(parts) >= 2 and not (pkg / parts[1]).is_dir():
            return False
        return len(parts) < 3 or (pkg / parts[1] / f'{parts[2]}.{parts[1]}').exists()
    base = pkg / parts[0]
    i = 1
    while i < len(parts):
        nxt = base / parts[i]
        if nxt.is_dir():
            base, i = nxt, i + 1
        elif nxt.with_suffix('.py').exists():
            base, i = nxt.with_suffix('.py'), i + 1
            break
        else:
            break
    if i == len(parts):
        return True
    if base.is_dir():
        base = base / '__init__.py'
        if not base.exists():
            return False
    if not base.suffix == '.py':
        return False
    return re.search(rf'\b{re.escape(parts[i])}\b', _module_text(base)) is not None


@lru_cache(maxsize=None)
def _git_has(sha: str, path: str) -> bool | None:
    if not (ROOT / '.git').exists():
        return None
    r = subprocess.run(['git', '-C', str(ROOT), 'cat-file', '-e', f'{sha}:{path}'],
                       capture_output=True, timeout=10)
    return r.returncode == 0


def _section_file(name: str, here: Path) -> Path | None:
    if name.endswith(('README', 'PERFORMANCE')):
        name += '.md'
    for folder in (here, *here.parents):              # PROTOCOL.md from its package's code
        if (folder / name).exists():
            return folder / name
        if folder == ROOT:
            break
    return None


# ------------------------------------------------------------------ the check
@lru_cache(maxsize=None)
def problems_in(path: Path) -> tuple[tuple[str, str], ...]:
    """(reference, what is wrong) for every dangling reference in one file."""
    text = path.read_text(encoding='utf-8', errors='replace')
    here = path.parent
    out = []
    is_md = path.suffix == '.md'
    if is_md:
        for target in LINK_RE.findall(text):
            if re.match(r'[a-z]+:', target):
                continue
            file, _, anchor = target.partition('#')
            dest = (here / file) if file else path
            if not dest.exists():
                out.append((target, 'no such file'))
            elif anchor and dest.suffix == '.md' and anchor not in headings(dest)[1]:
                out.append((target, 'no such anchor'))
    for m in PATH_RE.finditer(text):
        ref = m.group(1).rstrip('.')
        after = text[m.end():m.end() + 1]
        before = text[max(0, m.start() - 60):m.start()]
        if after in '*{<[' and after or ref.endswith('_') or not _is_repo_path(ref, here):
            continue
        if re.search(r'(?<![\w/.-])([\w.-]+)/[\w.-]+,\s*$', before) and \
                re.search(r'(?<![\w/.-])([\w.-]+)/[\w.-]+,\s*$', before).group(1) not in _tracked_top():
            continue                                      # owner/repo, docs/spec.md: another project's
        if _resolve(ref, here) is None:
            out.append((ref, 'no such file'))
    for name in MODULE_RE.findall(text):
        if not _module_exists(name.rstrip('.')):
            out.append((name, 'no such module or name'))
    for m in SECTION_RE.finditer(text):
        file, title = m.groups()
        title = re.sub(r'\s*\n\s*#?\s*', ' ', title)
        where = _section_file(file, here)
        ref = re.sub(r'\s*\n\s*#?\s*', ' ', m.group(0))
        if where is None:
            out.append((ref, 'no such file'))
        elif where.suffix == '.md' and not _has_section(where, title):
            out.append((ref, 'no such section'))
    for m in NUMBERED_RE.finditer(text):
        file, number = m.groups()
        where = _section_file(file, here)
        if where is not None and not any(re.match(rf'{number}[.\s]', t) for t in headings(where)[0]):
            out.append((m.group(0), 'no section of that number'))
    for file, anchor in ANCHOR_RE.findall(text):
        where = _section_file(file, here)
        if where is None or anchor not in headings(where)[1]:
            out.append((f'{file}#{anchor}', 'no such anchor'))
    for sha, file in GIT_SHOW_RE.findall(text):
        if _git_has(sha, file) is False:
            out.append((f'git show {sha}:{file}', 'not in the history'))
    return tuple(out)


def test_every_named_file_module_and_section_exists():
    found = []
    for path in documents() + sources():
        rel = str(path.relative_to(ROOT))
        found += [f'{rel}: {ref!r}: {why}' for ref, why in problems_in(path) if (rel, ref) not in ALLOWED]
    assert not found, 'dangling references:\n' + '\n'.join(sorted(set(found)))


def test_allowed_references_are_still_dangling():
    """An entry of ALLOWED whose reference was fixed is removed from it."""
    stale = [entry for entry in sorted(ALLOWED)
             if (ROOT / entry[0]).exists()
             and entry[1] not in [ref for ref, _ in problems_in(ROOT / entry[0])]]
    assert not stale, f'fixed, remove from ALLOWED: {stale}'


def test_readme_is_a_front_door():
    """README.md fits on a few screens and its map names every top-level folder."""
    lines = (ROOT / 'README.md').read_text(encoding='utf-8').splitlines()
    assert len(lines) <= 250, f'README.md has {len(lines)} lines (at most 250)'
    folders = sorted(p.name for p in ROOT.iterdir() if p.is_dir() and p.name in _tracked_top())
    text = '\n'.join(lines)
    missing = [f for f in folders if f'`{f}/`' not in text and f'[{f}/]' not in text
               and f'`{f}`' not in text]
    assert not missing, f'README.md: the map of the packages misses {missing}'
