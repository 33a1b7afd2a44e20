"""The project's import graph, read with ast (nothing imported): which modules each module of ffjax/, configs/ and
experiments/ imports, anywhere in its file (a function-level import too), and the closure of that graph: every
file a command runs. experiments.status takes an experiment's number sources from it; tests/test_import_graph
checks the graph's layers with it."""

from __future__ import annotations

import ast
import functools
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("ffjax", "configs", "experiments")


def modules(root: Path = ROOT) -> dict[str, Path]:
    """{dotted name: file} of every module in the three packages (a package is its __init__.py)."""
    out = {}
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def imported(name: str, path: Path, known: dict) -> set[str]:
    """The project modules `name` imports anywhere in its file: `from a.b import c` is a.b.c when that is a
    module, else a.b; relative imports are resolved against the module's package."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names]
        else:
            continue
        for t in targets:
            while t and t not in known:  # `import a.b.c` of a name inside a module: the module
                t = t.rpartition(".")[0]
            if t and t != name:
                found.add(t)
    return found


@functools.lru_cache(maxsize=4)
def graph(root: Path = ROOT) -> dict[str, set[str]]:
    """{module: the project modules it imports}."""
    known = modules(root)
    return {name: imported(name, path, known) for name, path in known.items()}


def closure(roots, root: Path = ROOT) -> set[str]:
    """Every module that running `roots` (dotted names) imports, directly or not, with the packages above each
    (importing a.b runs a/__init__.py first)."""
    g = graph(root)
    todo, seen = [r for r in roots if r in g], set()
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        parents = [".".join(m.split(".")[:i]) for i in range(1, m.count(".") + 1)]
        todo += [t for t in (*g[m], *parents) if t in g and t not in seen]
    return seen


def files(names, root: Path = ROOT) -> list[str]:
    """The repository paths of modules, sorted."""
    known = modules(root)
    return sorted(str(known[n].relative_to(root)) for n in names)
