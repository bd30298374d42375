"""The packages' modules import each other without a circle (function-level imports included)."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

ROOT = Path(__file__).resolve().parents[1]


def _imports() -> dict[str, set[str]]:
    """Module -> the project modules it imports anywhere in its source."""
    files = {}
    for pkg in ("leovr", "odometry", "selfsup"):
        for p in (ROOT / pkg).rglob("*.py"):
            name = ".".join(p.relative_to(ROOT).with_suffix("").parts)
            files[name.removesuffix(".__init__")] = p
    edges: dict[str, set[str]] = {m: set() for m in files}
    for m, p in files.items():
        for node in ast.walk(ast.parse(p.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                subs = [f"{node.module}.{a.name}" for a in node.names if f"{node.module}.{a.name}" in files]
                targets = subs or ([node.module] if node.module in files else [])
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names if a.name in files]
            else:
                continue
            edges[m].update(t for t in targets if t != m)
    return edges


def _circles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (scipy's csgraph)."""
    names = sorted(edges)
    index = {n: k for k, n in enumerate(names)}
    rows = [index[m] for m in names for t in edges[m]]
    cols = [index[t] for m in names for t in edges[m]]
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(names), len(names)))
    _, label = connected_components(graph, directed=True, connection="strong")
    groups = [[n for n, lab in zip(names, label) if lab == k] for k in np.unique(label)]
    return sorted(g for g in groups if len(g) > 1)


def test_the_circle_finder_finds_a_circle():
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_no_module_imports_itself_back_through_others():
    assert _circles(_imports()) == []
