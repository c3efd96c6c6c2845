"""The packages import one way only: no cycle between them, and each imports only packages of
the layers below its own.

Read (text only: nothing is imported, no ROS): every ``.py`` file of every ``rwpend_*`` folder of
the repository -- the package's own code and its ``setup.py``, not its ``test/`` folder -- and
its absolute imports of other ``rwpend_*`` packages, at module level and inside functions
(``import rwpend_model.rig``, ``from rwpend_ros.qos import QOS_CONTROL``). A command that runs
a module of a higher package names it as a string (``./rwpend``'s
``rwpend_bringup.cli.DELEGATED``, a process's module in ``rwpend_bringup.stack``): not an
import.

The layers, lowest first (:data:`LAYERS`): the plant model; the ROS plumbing; the nodes (plant,
estimator, controller); the bags; the loop; the command line and the launcher; the book's
experiments; identification, the console and the robustness studies; the harness that measures
the stack. A package may import packages of lower layers only; an import within a layer is an
error too. The generated interfaces (rwpend_msgs) may be imported anywhere. A new ``rwpend_*``
folder needs a layer here before the test passes.
"""
from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: the packages' layers, lowest first: a package may import only packages of lower layers
LAYERS: tuple[tuple[str, ...], ...] = (
    ('rwpend_model',),
    ('rwpend_ros',),
    ('rwpend_sim', 'rwpend_driver', 'rwpend_estimation', 'rwpend_control'),
    ('rwpend_bag',),
    ('rwpend_loop',),
    ('rwpend_bringup',),
    ('rwpend_lab',),
    ('rwpend_ident', 'rwpend_console', 'rwpend_sweep'),
    ('rwpend_bench',),
)
#: packages every layer may import: the generated interfaces
EVERYWHERE = frozenset({'rwpend_msgs'})
#: folders of a package that are not its code
NOT_CODE = frozenset({'test', '__pycache__', 'build', 'install', 'log'})


@dataclass(frozen=True)
class Edge:
    """One import of package ``dst`` by a file of package ``src``."""
    src: str
    dst: str
    module: str     # the module imported, e.g. rwpend_bringup.cli
    file: str       # relative to the tree's root
    line: int

    def where(self) -> str:
        return f'{self.file}:{self.line}'


#: the names of the packages' folders start with this
PREFIX = 'rwpend_'


def package_folders(root: Path, prefix: str = PREFIX) -> list[str]:
    """The package folders (``rwpend_*``) at the top of ``root``."""
    return sorted(p.name for p in root.iterdir() if p.is_dir() and p.name.startswith(prefix))


def code_files(root: Path, package: str) -> list[Path]:
    """The ``.py`` files of ``package``'s folder that are its code (not ``test/``)."""
    base = root / package
    return sorted(f for f in base.rglob('*.py')
                  if not (set(f.relative_to(base).parts[:-1]) & NOT_CODE)
                  and not any(part.endswith('.egg-info') for part in f.relative_to(base).parts))


def imports_of(path: Path) -> list[tuple[str, int]]:
    """(module, line) of every absolute import in ``path``, anywhere in the file."""
    tree = ast.parse(path.read_text(encoding='utf-8'), filename=str(path))
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(alias.name, node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.module, node.lineno))
    return sorted(out, key=lambda m: m[1])


def edges_of(root: Path, prefix: str = PREFIX) -> list[Edge]:
    """Every import of one package (``rwpend_*``) by another under ``root``."""
    edges = []
    for package in package_folders(root, prefix):
        for f in code_files(root, package):
            for module, line in imports_of(f):
                top = module.split('.')[0]
                if top.startswith(prefix) and top != package:
                    edges.append(Edge(package, top, module, str(f.relative_to(root)), line))
    return edges


def _components(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of ``graph`` (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _cycle_through(start: str, members: set[str], graph: dict[str, set[str]]) -> list[str]:
    """A shortest cycle through ``start`` within ``members`` (a component of more than one
    package): [start, ..., start]."""
    paths = {start: [start]}
    queue = [start]
    while queue:
        v = queue.pop(0)
        for w in sorted(graph.get(v, ())):
            if w == start:
                return paths[v] + [start]
            if w in members and w not in paths:
                paths[w] = paths[v] + [w]
                queue.append(w)
    raise AssertionError(f'no cycle through {start} in {sorted(members)}')


def cycles(edges: list[Edge]) -> list[str]:
    """One report per group of packages that import each other in a circle: a shortest cycle
    through each of them, and the file:line of each import of those cycles."""
    graph: dict[str, set[str]] = {}
    for e in edges:
        graph.setdefault(e.src, set()).add(e.dst)
        graph.setdefault(e.dst, set())
    reports = []
    for comp in _components(graph):
        if len(comp) < 2:
            continue
        found: list[list[str]] = []
        for v in comp:
            c = _cycle_through(v, set(comp), graph)[:-1]
            i = c.index(min(c))
            c = c[i:] + c[:i] + [min(c)]         # the same cycle, whichever package it was found from
            if c not in found:
                found.append(c)
        lines = [f'packages importing each other in a circle: {", ".join(comp)}']
        for cycle in found:
            lines.append(f'  cycle {" -> ".join(cycle)}')
            for a, b in zip(cycle, cycle[1:]):
                lines += [f'    {e.where()}: {a} imports {e.module}'
                          for e in edges if (e.src, e.dst) == (a, b)]
        reports.append('\n'.join(lines))
    return reports


def layer_problems(root: Path, edges: list[Edge], layers=LAYERS, everywhere=EVERYWHERE,
                   prefix: str = PREFIX) -> list[str]:
    """A folder without a layer, and every import of a package that is not in a lower layer
    (file:line: what is imported, and the two layers)."""
    rank = {p: i for i, layer in enumerate(layers) for p in layer}
    problems = [f'{p}/: a {prefix}* folder without a layer: add it to LAYERS in tests/test_layering.py'
                for p in package_folders(root, prefix) if p not in rank and p not in everywhere]
    for e in edges:
        if e.dst in everywhere or e.src not in rank:
            continue
        if e.dst not in rank:
            problems.append(f'{e.where()}: {e.src} imports {e.module}: {e.dst} has no layer')
        elif rank[e.dst] >= rank[e.src]:
            how = 'its own layer' if rank[e.dst] == rank[e.src] else 'a higher layer'
            problems.append(f'{e.where()}: {e.src} (layer {rank[e.src]}) imports {e.module}: '
                            f'{e.dst} is in {how} ({rank[e.dst]})')
    return problems


# ------------------------------------------------------------------ the repository
def test_every_package_folder_has_a_layer():
    rank = {p for layer in LAYERS for p in layer}
    assert len(rank) == sum(len(layer) for layer in LAYERS), 'a package in two layers'
    missing = [p for p in package_folders(ROOT) if p not in rank and p not in EVERYWHERE]
    assert not missing, '\n'.join(f'{p}/: a rwpend_* folder without a layer: add it to LAYERS in '
                                  'tests/test_layering.py' for p in missing)


def test_no_import_cycle_between_packages():
    found = cycles(edges_of(ROOT))
    assert not found, '\n\n'.join(found)


def test_packages_import_only_lower_layers():
    problems = layer_problems(ROOT, edges_of(ROOT))
    assert not problems, f'{len(problems)} imports against the layers:\n' + '\n'.join(problems)


def test_the_scan_sees_the_packages_imports():
    """The scan reads what it should: imports in functions too, not the test folders."""
    edges = edges_of(ROOT)
    assert any(e.src == 'rwpend_bringup' and e.dst == 'rwpend_model' for e in edges)
    assert {e.src for e in edges} >= {'rwpend_ros', 'rwpend_control', 'rwpend_bringup', 'rwpend_bench'}
    assert not any('/test/' in e.file for e in edges)


# ------------------------------------------------------------------ the checker
def _tree(root: Path, files: dict[str, str]) -> Path:
    for name, text in files.items():
        f = root / name
        f.parent.mkdir(parents=True, exist_ok=True)
        f.write_text(text)
    return root


def test_the_checker_reports_a_cycle_with_each_import(tmp_path):
    """A tree of packages pkg_* (prefix 'pkg_': its names are no modules of this repository)."""
    root = _tree(tmp_path, {
        'pkg_a/pkg_a/__init__.py': '',
        'pkg_a/pkg_a/x.py': 'import os\n\n\ndef f():\n    from pkg_b.y import g\n    return g\n',
        'pkg_b/pkg_b/y.py': 'import pkg_c.z\n\n\ndef g():\n    pass\n',
        'pkg_c/pkg_c/z.py': 'from pkg_a import x\nfrom pkg_msgs.msg import M\n',
        'pkg_c/test/test_z.py': 'import pkg_d\n',        # a test folder: not read
        'pkg_c/pkg_c/rel.py': 'from . import z\n',       # the package itself: no edge
        'pkg_d/pkg_d/w.py': 'from pkg_a.x import f\n',
        'other/t.py': 'import pkg_d\n',                  # not a package folder
    })
    edges = edges_of(root, 'pkg_')
    assert {(e.src, e.dst, e.where()) for e in edges} == {
        ('pkg_a', 'pkg_b', 'pkg_a/pkg_a/x.py:5'), ('pkg_b', 'pkg_c', 'pkg_b/pkg_b/y.py:1'),
        ('pkg_c', 'pkg_a', 'pkg_c/pkg_c/z.py:1'), ('pkg_c', 'pkg_msgs', 'pkg_c/pkg_c/z.py:2'),
        ('pkg_d', 'pkg_a', 'pkg_d/pkg_d/w.py:1')}
    [report] = cycles(edges)
    assert report.splitlines() == [
        'packages importing each other in a circle: pkg_a, pkg_b, pkg_c',
        '  cycle pkg_a -> pkg_b -> pkg_c -> pkg_a',
        '    pkg_a/pkg_a/x.py:5: pkg_a imports pkg_b.y',
        '    pkg_b/pkg_b/y.py:1: pkg_b imports pkg_c.z',
        '    pkg_c/pkg_c/z.py:1: pkg_c imports pkg_a']

    # without the upward import of pkg_c, no cycle (pkg_d imports downward only)
    assert cycles([e for e in edges if e.src != 'pkg_c']) == []

    layers = (('pkg_a',), ('pkg_b', 'pkg_c'))
    assert layer_problems(root, edges, layers, {'pkg_msgs'}, 'pkg_') == [
        'pkg_d/: a pkg_* folder without a layer: add it to LAYERS in tests/test_layering.py',
        'pkg_a/pkg_a/x.py:5: pkg_a (layer 0) imports pkg_b.y: pkg_b is in a higher layer (1)',
        'pkg_b/pkg_b/y.py:1: pkg_b (layer 1) imports pkg_c.z: pkg_c is in its own layer (1)']
    assert layer_problems(root, [Edge('pkg_b', 'pkg_d', 'pkg_d.w', 'pkg_b/pkg_b/v.py', 3)],
                          layers, {'pkg_msgs'}, 'pkg_')[1:] == [
        'pkg_b/pkg_b/v.py:3: pkg_b imports pkg_d.w: pkg_d has no layer']


def test_each_package_declares_the_packages_it_imports():
    """package.xml (what colcon and rosdep read) lists every rwpend_* package the code imports,
    as an ``exec_depend`` (or ``depend``)."""
    import re
    missing = []
    edges = edges_of(ROOT)
    for pkg in package_folders(ROOT):
        xml = ROOT / pkg / 'package.xml'
        if not xml.is_file():
            continue
        declared = set(re.findall(r'<(?:exec_)?depend>(rwpend_\w+)</(?:exec_)?depend>', xml.read_text()))
        for dst in sorted({e.dst for e in edges if e.src == pkg} - declared):
            missing.append(f'{pkg}/package.xml: no <exec_depend>{dst}</exec_depend> (imported by '
                           f'{next(e.where() for e in edges if e.src == pkg and e.dst == dst)})')
    assert not missing, '\n'.join(missing)
