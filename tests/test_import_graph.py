"""The import graph of ffjax/, configs/ and experiments/ (read with ast, nothing imported): the packages form
layers (LAYERS: each imports only from the layers below it), the library never imports the experiments, no
modules import each other in a circle, and the experiment kernel's functions stay short. Every import counts,
function-level ones too: a lazy import still ties the modules together."""

import ast
from pathlib import Path

import pytest

from experiments import imports

ROOT = Path(__file__).resolve().parent.parent
MAX_LINES = 80
# Files whose functions must stay under MAX_LINES (issue 15; ffjax/train's are checked in tests/test_train.py).
SHORT_FUNCTIONS = ("experiments/kernel.py",)


# The package-level layers, lowest first. A unit (a package of ffjax, a top-level ffjax module, configs,
# experiments) imports from its own unit and from the layers below it, never from its own layer or above.
LAYERS = (
    ("ffjax.errors", "ffjax.compile_cache"),  # the error types (imports nothing); jax's compile cache
    ("ffjax.files", "ffjax.jsontree"),  # files on disk; JSON trees
    ("ffjax.cli", "ffjax.results"),  # one-line errors of every CLI; results files
    ("ffjax.data",),  # splits on disk and the input pipeline
    ("ffjax.sim",),  # the simulator: no configs, no models
    ("configs",),  # presets, keys and checks (the sensor names come from sim)
    ("ffjax.models", "ffjax.metrics"),
    ("ffjax.registry",),  # ablations as data
    ("ffjax.store",),  # trained models on disk: model.json, checkpoints, bundles, converted weights
    ("ffjax.convert",),  # PyTorch weights -> ffjax.store's converted folders
    ("ffjax.train",),
    ("ffjax.inference", "ffjax.simulate"),
    ("ffjax.calibrate", "ffjax.export", "ffjax.live", "ffjax.tasks"),
    ("experiments",),
)


def _unit(module: str) -> str:
    """The layered unit a module belongs to: ffjax.<first part>, configs or experiments."""
    parts = module.split(".")
    return ".".join(parts[:2]) if parts[0] == "ffjax" and len(parts) > 1 else parts[0]


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    return imports.graph(ROOT)


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index, low, stack, on_stack, out = {}, {}, [], set(), []

    def visit(v):
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
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def _path(graph: dict, comp: list[str]) -> str:
    """One circle through a component, 'a -> b -> a', for the failure message."""
    members, start = set(comp), comp[0]
    trail, seen = [start], {start}
    while True:
        nxt = sorted(w for w in graph[trail[-1]] if w in members)
        back = [w for w in nxt if w == start]
        if back and len(trail) > 1:
            return " -> ".join(trail + [start])
        fresh = [w for w in nxt if w not in seen]
        if not fresh:  # every successor is on the trail: the circle closes there
            return " -> ".join(trail[trail.index(nxt[0]):] + [nxt[0]])
        trail.append(fresh[0])
        seen.add(fresh[0])


def test_the_graph_sees_every_kind_of_import(graph):
    assert "ffjax.train.loop" in graph["ffjax.train"]  # from-import of a name, package __init__
    assert "experiments.kernel" in graph["experiments.ablation"]  # `from experiments import kernel`
    assert "ffjax.train.pretrain" in graph["experiments.kernel"]  # a function-level import of a module
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def test_the_library_never_imports_the_experiments(graph):
    up = {m: sorted(t for t in ts if t.split(".")[0] == "experiments") for m, ts in graph.items()
          if m.split(".")[0] in ("ffjax", "configs")}
    assert not {m: ts for m, ts in up.items() if ts}, "library modules importing experiments"


def test_every_unit_has_a_layer(graph):
    layered = {u for layer in LAYERS for u in layer}
    assert not {_unit(m) for m in graph} - layered - {"ffjax"}, "units missing from LAYERS"


def test_packages_import_only_from_layers_below(graph):
    level = {u: i for i, layer in enumerate(LAYERS) for u in layer}
    up = sorted(f"{m} -> {t} ({_unit(m)} is layer {level[_unit(m)]}, {_unit(t)} is layer {level[_unit(t)]})"
                for m, ts in graph.items() for t in ts
                if _unit(m) != _unit(t) and _unit(m) in level and level[_unit(t)] >= level[_unit(m)])
    assert not up, "imports that go sideways or up the layers:\n" + "\n".join(up)


def test_the_layer_check_sees_an_upward_import():
    level = {u: i for i, layer in enumerate(LAYERS) for u in layer}
    assert level[_unit("ffjax.sim.dataset")] < level[_unit("configs.base")]  # sim must not import configs
    assert _unit("ffjax.store.trained") == "ffjax.store" and _unit("configs") == "configs"


def test_no_import_cycles(graph):
    found = _cycles(graph)
    assert not found, "import circles:\n" + "\n".join(_path(graph, c) for c in found)


def _long_functions(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), str(path))
    return [f"{path.relative_to(ROOT)}:{n.lineno} {n.name}: {n.end_lineno - n.lineno + 1} lines"
            for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))
            and n.end_lineno - n.lineno + 1 > MAX_LINES]


@pytest.mark.parametrize("rel", SHORT_FUNCTIONS)
def test_no_function_over_80_lines(rel):
    assert not _long_functions(ROOT / rel)
