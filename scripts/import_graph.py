"""The package's import graph, checked: no circle between modules, no import from a lower layer to a higher one.

    python scripts/import_graph.py

Reads every import statement, at module level or inside a function, with grimp (what `lint-imports` builds on),
so a lazy import counts as much as a top-level one. Prints each circle (a strongly connected set of modules) and
each import that climbs the layers of `[tool.importlinter]`; exits 1 when there is any.
"""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path

import grimp

ROOT = Path(__file__).resolve().parents[1]


def circles(graph: grimp.ImportGraph) -> list[list[str]]:
    """The strongly connected sets of more than one module (Tarjan's algorithm, iterative)."""
    edges = {m: sorted(graph.find_modules_directly_imported_by(m)) for m in sorted(graph.modules)}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for root in edges:
        if root in index:
            continue
        work = [(root, 0)]
        while work:
            v, i = work.pop()
            if i == 0:
                index[v] = low[v] = len(index)
                stack.append(v)
                on_stack.add(v)
            if i < len(edges[v]):
                work.append((v, i + 1))
                w = edges[v][i]
                if w not in index:
                    work.append((w, 0))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            for w in edges[v]:
                if w in on_stack:
                    low[v] = min(low[v], low[w])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    found.append(sorted(comp))
    return found


def upward_imports(graph: grimp.ImportGraph) -> list[str]:
    """Imports from a module of a lower layer to one of a higher layer (the contract's `layers`, top first)."""
    contract = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]["contracts"][0]
    rank = {f"digail.{name.strip()}": r for r, layer in enumerate(contract["layers"]) for name in layer.split("|")}

    def layer_of(module: str) -> int | None:
        parts = module.split(".")
        return rank.get(".".join(parts[:2]))

    out = []
    for m in sorted(graph.modules):
        for imported in sorted(graph.find_modules_directly_imported_by(m)):
            a, b = layer_of(m), layer_of(imported)
            if a is not None and b is not None and b < a:
                out.append(f"{m} -> {imported}")
    return out


def main() -> int:
    graph = grimp.build_graph("digail", cache_dir=None)
    found, up = circles(graph), upward_imports(graph)
    for c in found:
        print("circle: " + " <-> ".join(c))
    for line in up:
        print("upward: " + line)
    print(f"{len(graph.modules)} modules: {len(found)} circle(s), {len(up)} upward import(s)")
    return 1 if found or up else 0


if __name__ == "__main__":
    sys.exit(main())
