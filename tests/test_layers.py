"""The folder tree is the architecture: imports between the layers of ``sern_jax`` point one
way, down, and the module graph has no circle (docs/ARCHITECTURE.md)."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "sern_jax"

# lower rank = lower layer; a module may import its own layer and any lower one
RANK = {"core": 0, "infra": 0, "analysis": 1, "learners": 2, "engine": 3, "grasp": 4,
        "experiment": 5, "bench": 5, "commands": 6}
# third-party packages the pure core may import
CORE_DEPS = {"jax", "numpy", "optax", "scipy", "math", "functools", "typing", "dataclasses",
             "collections", "enum", "itertools", "__future__", "operator", "warnings"}


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """Absolute names a module imports (``from a.b import c`` gives a.b and a.b.c)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            subs = {f"{node.module}.{a.name}" for a in node.names}
            modules = subs & set(MODULES)
            # ``from pkg import mod`` imports mod (the package's own __init__ is not an edge)
            out |= modules if modules == subs else subs | {node.module}
    return out


MODULES = {_module_name(p): p for p in PKG.rglob("*.py") if "__pycache__" not in p.parts}


def _layer(name: str) -> str | None:
    parts = name.split(".")
    return parts[1] if parts[0] == "sern_jax" and len(parts) > 1 else None


def test_every_module_belongs_to_a_layer_and_the_top_is_small():
    top = sorted(p.name for p in PKG.glob("*.py"))
    assert top == ["__init__.py"], top
    layers = {_layer(m) for m in MODULES if _layer(m)}
    assert layers == set(RANK), layers ^ set(RANK)


def _edges() -> list[tuple[str, str]]:
    edges = []
    for mod, path in MODULES.items():
        for name in _imports(path):
            # a package's __init__ that the module lives in is not an edge (it runs first)
            if name.startswith("sern_jax.") and name in MODULES and name != mod \
                    and not mod.startswith(name + "."):
                edges.append((mod, name))
    return edges


def test_imports_point_down():
    up = [(a, b) for a, b in _edges()
          if _layer(a) and _layer(b) and RANK[_layer(b)] > RANK[_layer(a)]]
    assert not up, f"imports pointing up: {up}"
    # the core and the infrastructure are both at the bottom, and independent
    across = [(a, b) for a, b in _edges()
              if {_layer(a), _layer(b)} == {"core", "infra"}]
    assert not across, across


def test_the_module_graph_has_no_circle():
    graph: dict[str, set[str]] = {}
    for a, b in _edges():
        graph.setdefault(a, set()).add(b)
    state: dict[str, int] = {}

    def visit(node, stack):
        state[node] = 1
        for nxt in graph.get(node, ()):
            if state.get(nxt) == 1:
                raise AssertionError(f"import circle: {' -> '.join(stack + [node, nxt])}")
            if nxt not in state:
                visit(nxt, stack + [node])
        state[node] = 2

    for node in list(graph):
        if node not in state:
            visit(node, [])


def test_the_core_imports_only_jax_numpy_optax_and_scipy():
    for mod, path in MODULES.items():
        if _layer(mod) != "core":
            continue
        tops = {n.split(".")[0] for n in _imports(path) if not n.startswith("sern_jax")}
        assert tops <= CORE_DEPS, (mod, tops - CORE_DEPS)
        text = path.read_text()
        for word in ("threading", "os.environ", "open("):
            assert word not in text, (mod, word)


def test_the_checks_can_fail():
    # control: an upward edge and a circle are found where they exist
    global MODULES
    saved = MODULES
    try:
        fake = ROOT / "tests" / "data" / "layer_control"
        MODULES = {**saved, "sern_jax.core.fake_up": fake / "up.py"}
        with pytest.raises(AssertionError, match="pointing up"):
            test_imports_point_down()
        MODULES = {**saved, "sern_jax.core.fake_a": fake / "a.py",
                   "sern_jax.core.fake_b": fake / "b.py"}
        with pytest.raises(AssertionError, match="circle"):
            test_the_module_graph_has_no_circle()
    finally:
        MODULES = saved
